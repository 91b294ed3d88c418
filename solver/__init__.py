"""naocal's solver: the robot description, the camera model, the measurement model and its effects (one module each
in solver/effects/), the parameter registry, identification and diagnostics. Pure computation: no robot, no I/O
except the robot description, dataset and offsets readers and writers."""

from solver.moved import alias_moved_modules  # noqa: E402

# The synthesiser of test data moved out of the solver (sim.synthetic); the old name imports until the next release.
alias_moved_modules({"solver.synthetic": "sim.synthetic"})
