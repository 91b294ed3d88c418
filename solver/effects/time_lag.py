"""Time lag: the image is stamped dt later than the joint readings it is paired with.

    q_true = theta - c + q_dot * dt       (q_dot: dataset columns vel_<J>, rad/s at t_joints_s)

Only images taken while the joints move carry it (the agent's lag probe).
"""

import numpy as np

from naocal.solver import fields
from naocal.solver.effect import Effect, JointTerm, MockPerturbation, Parameter


class TimeLag(Effect):
    name = "time_lag"
    order = 60
    summary = "one lag dt between the image and joint clocks (+ joint velocity * dt; needs vel_<Joint> columns)"
    plausible_limit = 0.2  # s
    uses_velocity = True
    no_signal_hint = "every image was taken with the joints still: capture while moving to see a time lag"
    offsets_section, offsets_key = "head", "time_lag_s"
    offsets_limit = 1.0
    mock_size_unit, mock_stream = "s", 7

    def parameters(self, setup):
        return [Parameter("time_lag.dt", self.name, "s", 0.01, component="dt")]

    def joint_terms(self, layout):
        velocity = layout.data.velocity
        if velocity is None:
            raise ValueError("the time_lag effect needs joint velocities (vel_<Joint> columns) in the dataset")
        return [JointTerm(i, c, velocity[:, c]) for i, _ in layout.params(self.name) for c in range(velocity.shape[1])]

    def untestable_reason(self, data):
        if data.velocity is None:
            return "needs joint velocities (vel_<Joint> columns), which this dataset lacks"
        return ""

    def partial_residual_panels(self, fit):
        from naocal.solver.diagnostics import apparent_errors, partial_residuals

        data = fit.model.data
        # One parameter drives every joint: show the lag each moving image implies on its own.
        lag = apparent_errors(fit, ["time_lag.dt"], partial_residuals(fit, ["time_lag.dt"]))[:, 0]
        ok = np.isfinite(lag)
        if not ok.any():
            return []
        speed = np.linalg.norm(data.velocity, axis=1)
        xs = np.array([speed[ok].min(), speed[ok].max()])
        return [(speed[ok], lag[ok] * 1e3, "joint speed |q_dot| (rad/s)", "apparent time lag (ms)", data.target[ok],
                 (xs, np.full(2, fit.value("time_lag.dt") * 1e3)))]

    def mock_perturbation(self, rng, size, setup):
        """Images stamped `size` later than their true exposure."""
        return MockPerturbation(image_stamp_late_s=float(size), record={"image_stamp_late_s": float(size)})

    def write_offsets(self, values, setup):
        return {"dt": float(values["time_lag.dt"])} if "time_lag.dt" in values else {}

    def read_offsets(self, content, path, where, robot):
        fields.json_object(content, path, where, ("dt",), ())
        fields.number(content["dt"], path, f"{where}.dt", limit=self.offsets_limit, unit="s")


EFFECT = TimeLag()
