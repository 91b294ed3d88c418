"""The one identification routine: from a dataset to a fitted model, as `naocal identify`, `naocal diagnose` and
the agent all do it.

What the data decide here, rather than an assumption:
- which joint angle to trust: each hypothesis (the reading, the reading's step with the command inside it, the
  command) is fitted and the one that explains the images best is used; every hypothesis's RMS is reported;
- which corners are mis-detections: a corner that no rigid motion of its board explains, far beyond the robust
  (MAD) scale of the others, is set aside and reported by image and vertex with its size;
- which images are no view of their board at all: before fitting, an image whose corners no homography of its flat
  board explains (solver.image_check) is set aside whole; after the corner trimming, so is an image that lost more
  than a third of its corners, or else a still image the fit leaves far beyond all others (the trimming then goes on
  without it, within its one budget of rounds); each is reported with its reason;
- how precisely the offsets are known: the readings' quantisation joins the standard deviations (solver.identify).
The robot description's shared motors (the NAO's HipYawPitch pair) take one offset. Captures taken while the
joints move are fitted only when the model has an effect for them (time_lag); otherwise their angles are off by
velocity x lag and they are set aside (diagnose keeps them: they are how it tests time_lag).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from naocal.solver.adapter import model_data_from_dataset
from naocal.solver.effects import EFFECTS
from naocal.solver.identify import (MAD_TO_SIGMA, MAX_TRIM_ROUNDS, OUTLIER_SCALES, IdentificationResult, identify,
                             trimmed)
from naocal.solver.image_check import (ImageCheck, SetAsideImage, check_images, describe_set_aside, lost_too_many,
                                 without_images)
from naocal.solver.model import ModelData
from naocal.solver.quantisation import reading_resolution
from naocal.solver.registry import Registry

# The angle hypotheses, in the order a tie is broken (the paper's choice first).
ANGLE_HYPOTHESES = ("measured", "cell", "commanded")
HYPOTHESIS_WORDS = {"measured": "the readings", "cell": "the command inside the reading's step",
                    "commanded": "the commands"}
# A hypothesis must fit this much better (relative RMS) than an earlier one in ANGLE_HYPOTHESES to be chosen.
ANGLE_MARGIN = 0.01
# Outliers: a corner whose non-rigid residual exceeds OUTLIER_SCALES robust scales (solver.identify's rule for
# every kind) and OUTLIER_MIN_PX (mis-detections are a square or a reflection off, several px).
OUTLIER_MIN_PX = 1.0
# After the trimming, images that lost too many corners (or the one far beyond the others) are set aside, the data
# refitted and the trimming goes on with the rounds it has left (at most this many times: each removes an image).
MAX_IMAGE_ROUNDS = 3
# A still image the fit leaves far beyond all others is a flat board's view in the wrong place (the other sandal, a
# lattice shifted by a square, a reflection), which the homography check cannot see: its RMS beyond the images'
# median RMS by IMAGE_SCALES robust (MAD) scales of the images' RMS, and beyond IMAGE_MIN_PX. Measured (base fits,
# tests/loop_cases.py seed 1): unmodelled elasticity, backlash, three effects, an axis tilt leave their worst image
# 2.4-6.2 scales above the median, the realistic mock 4.0; one image shifted by 10, 30 or 80 px: 28, 20, 14.
IMAGE_SCALES = 10.0
IMAGE_MIN_PX = 1.0
MIN_IMAGES_FOR_SCALE = 8
# GLS trusts the board's shape to this noise at least (the realistic mock's detections: 0.028 px robust scale).
GLS_MIN_SIGMA_PX = 0.02


@dataclass
class Outlier:
    image: int  # the dataset's image id
    vertex: int
    size_px: float  # |residual| of the corner at the final fit


def describe_angles(chosen: str, hypotheses, reading_step_rad: float) -> str:
    """One line: the joint angles used, and each hypothesis's RMS when the fit chose among them."""
    step = (f"readings quantised to {np.degrees(reading_step_rad):.4g} deg" if reading_step_rad > 0
            else "readings not quantised")
    if len(hypotheses) < 2:
        return f"joint angles: {HYPOTHESIS_WORDS[chosen]} (as asked); {step}"
    evidence = ", ".join(f"{HYPOTHESIS_WORDS[h.mode]} {h.rms_px:.3f} px" for h in hypotheses)
    return f"joint angles: {HYPOTHESIS_WORDS[chosen]}, chosen by the fit ({evidence}); {step}"


def describe_outliers(outliers, robust_scale_px: float, count: int = 8) -> str:
    """One line naming the corners set aside as mis-detections ([Outlier]), worst first."""
    if not outliers:
        return f"outliers: none (robust scale {robust_scale_px:.3f} px)"
    worst = sorted(outliers, key=lambda o: -o.size_px)[:count]
    listed = ", ".join(f"image {o.image} vertex {o.vertex} {o.size_px:.1f} px" for o in worst)
    images = len({o.image for o in outliers})
    return (f"outliers: {len(outliers)} corners in {images} images set aside as mis-detections (no rigid "
            f"board motion, so no physical effect, explains them; beyond {OUTLIER_SCALES:g} x the robust scale "
            f"{robust_scale_px:.3f} px): {listed}" + (" ..." if len(outliers) > count else ""))


@dataclass
class AngleHypothesis:
    mode: str
    rms_px: float  # over both coordinates, on the corners no hypothesis flagged
    n_outliers: int


@dataclass
class DatasetFit:
    """What identify_dataset did: the fitted data and result, and the evidence for its choices."""

    data: ModelData  # the fitted data (outliers and, without time_lag, moving captures set aside)
    result: IdentificationResult
    angles: str  # the chosen hypothesis
    hypotheses: list[AngleHypothesis]
    reading_step_rad: float  # the readings' encoder step (0: not quantised)
    outliers: list[Outlier] = field(default_factory=list)
    robust_scale_px: float = float("nan")  # MAD scale of the non-rigid residual (outliers cannot inflate it)
    n_moving_set_aside: int = 0
    gls: bool = False  # refined by generalised least squares (solver.gls), intrinsics free
    images_set_aside: list = field(default_factory=list)  # [solver.image_check.SetAsideImage], whole images
    image_check: ImageCheck | None = None  # the check before the fit (None: not robust)

    def describe_angles(self) -> str:
        return describe_angles(self.angles, self.hypotheses, self.reading_step_rad)

    def describe(self) -> str:
        method = ("\n  fitted by generalised least squares: the images of one held command share its error in the "
                  "step; intrinsics free; jackknife standard deviations" if self.gls else "")
        return f"{self.describe_angles()}\n  {self.describe_outliers()}{method}"

    def describe_outliers(self, count: int = 8) -> str:
        return describe_outliers(self.outliers, self.robust_scale_px, count)

    def describe_images(self) -> str:
        """One line naming the whole images set aside ('' when none was)."""
        return describe_set_aside(self.images_set_aside)

    def as_dict(self) -> dict:
        return {
            "angles": {"chosen": self.angles, "description": self.describe_angles(),
                       "reading_step_deg": float(np.degrees(self.reading_step_rad)),
                       "hypotheses": [{"mode": h.mode, "rms_px": h.rms_px, "n_outliers": h.n_outliers}
                                      for h in self.hypotheses]},
            "robust_scale_px": self.robust_scale_px,
            "outliers": [{"image": o.image, "vertex": o.vertex, "size_px": o.size_px} for o in self.outliers],
            "images_set_aside": [s.as_dict() for s in self.images_set_aside],
            "moving_captures_set_aside": self.n_moving_set_aside,
            "generalised_least_squares": self.gls,
        }


def identify_dataset(dataset, effects=(), *, angles: str = "auto", robust: bool = True, fixed=(),
                     tie_shared_motors: bool = True, moving: str = "auto", solver: str = "lm", loss: str = "linear",
                     loss_scale_px: float = 1.0, setup=None, gls: bool = False) -> DatasetFit:
    """Fit the base model plus `effects` to a read dataset (solver.dataset.Dataset): the routine every caller uses.

    angles : 'auto' (every hypothesis of ANGLE_HYPOTHESES is fitted, the best fit chosen) or one of them.
    robust : set aside corners no rigid board motion explains (mis-detections), found with a robust scale, and whole
        images no view of their flat board explains or that lost over a third of their corners (solver.image_check).
    moving : 'auto' (captures taken while moving are fitted only if an effect models them), 'all' or 'still'.
    solver, loss, loss_scale_px : as solver.identify.identify's.
    setup : the cameras and targets to parametrise (default: the data's); a target without captures keeps its
        nominal values (solver.identify fixes parameters without data).
    gls : when the readings win and are quantised, refine the fit by generalised least squares (solver.gls: the
        images that share a joint's command share its error in the step), with the cameras' intrinsics free (GLS
        leans on the board's perspective, which the prior intrinsics bias).
    Raises SolveError (solver.identify) when the data cannot determine the model.
    """
    effects = tuple(effects)
    modes = ANGLE_HYPOTHESES if angles == "auto" else (angles,)
    if angles != "auto" and angles not in ANGLE_HYPOTHESES:
        raise ValueError(f"unknown angle choice {angles!r}: expected auto or one of {', '.join(ANGLE_HYPOTHESES)}")
    fits, seen, check = {}, [], None
    for mode in modes:
        data = model_data_from_dataset(dataset, angles=mode)
        if any(np.array_equal(data.theta, other) for other in seen):
            continue  # the same angles as a hypothesis already fitted (unquantised readings: cell = measured)
        seen.append(data.theta)
        if robust:  # whole images no view of a flat board explains: the pixels decide, whatever the angles
            check = check or check_images(data)
            data = without_images(data, {s.image for s in check.set_aside}, check)
        data, n_moving = moving_handled(data, effects, moving)
        registry = Registry(effects, setup=setup or data.setup, tie_shared_motors=tie_shared_motors, fixed=fixed)
        step = _reading_step(dataset, data)
        options = dict(solver=solver, loss=loss, loss_scale_px=loss_scale_px)

        def refit(data, x0, registry=registry, step=step, options=options):
            return identify(data, registry, x0=x0, reading_step_rad=step, **options)

        fits[mode] = robust_fit(data, refit, robust=robust, homography_rms=check and check.rms_px) + (n_moving, step)
    chosen, hypotheses = choose_angles(fits)
    data, result, outliers, scale, dropped, n_moving, step = fits[chosen]
    use_gls = gls and chosen == "measured" and bool(np.any(step > 0))
    if use_gls:
        result = _gls_refined(data, result, step, scale, fixed, tie_shared_motors, solver)
    images = (check.set_aside if check else []) + dropped
    return DatasetFit(data, result, chosen, hypotheses, float(np.max(step, initial=0.0)), outliers, scale, n_moving,
                      use_gls, images, check)


def _gls_refined(data: ModelData, result, step, scale_px: float, fixed, tie_shared_motors, solver):
    """The GLS fit (solver.gls) from the ordinary one, intrinsics free; detector noise the robust scale of the
    non-rigid residual (at least GLS_MIN_SIGMA_PX)."""
    from naocal.solver.gls import identify_gls

    registry = result.registry
    effects = tuple(dict.fromkeys(registry.effects + ("intrinsics",)))
    registry = Registry(effects, setup=registry.setup, tie_shared_motors=tie_shared_motors, fixed=fixed)
    start = identify(data, registry, x0=registry.from_dict(result.registry.as_dict(result.values)), solver=solver)
    # (only its values are used: no quantisation covariance, which costs a dense Jacobian)
    sigma_px = max(scale_px, GLS_MIN_SIGMA_PX) if np.isfinite(scale_px) else GLS_MIN_SIGMA_PX
    return identify_gls(start.model.data, registry, start.values, step, sigma_px)


def moving_handled(data: ModelData, effects, moving: str):
    """(data, number set aside): the captures taken while moving set aside unless `effects` model them (or `moving`
    is 'all'): without time_lag their angles are off by velocity x lag (identify and verify alike)."""
    if data.velocity is None or moving == "all":
        return data, 0
    still = np.flatnonzero(np.all(data.velocity == 0.0, axis=1))
    if len(still) == data.n_images or (moving == "auto" and any(EFFECTS[e].uses_velocity for e in effects)):
        return data, 0
    return data.subset(still), data.n_images - len(still)


def _reading_step(dataset, data: ModelData) -> np.ndarray:
    """(J,) the encoder step of each joint's still readings (0: not quantised), whatever theta was chosen."""
    measured = dataset.as_v2().joint_matrix("")
    image = np.asarray(dataset.as_v2().columns["image"], dtype=np.int64)
    ids, first = np.unique(image, return_index=True)
    readings = measured[first]
    if data.velocity is not None:
        velocity = dataset.as_v2().joint_matrix("vel_")[first]
        readings = readings[np.all(velocity == 0.0, axis=1)]
    return reading_resolution(readings)


def robust_fit(data: ModelData, refit, x0=None, *, robust: bool = True, homography_rms=None):
    """(data, fit, outliers, robust scale, images set aside): the one rule for which corners and images are
    mis-detections, used by identify, diagnose, verify and the agent's verification (after solver.image_check's
    whole-image check: `set_aside_mis_detections`). Fit, set aside the corners only a mis-detection explains
    (MAX_TRIM_ROUNDS rounds in all), refit; then set aside whole an image that lost more than a third of its
    corners, or else the still image the fit leaves far beyond all others (_far_image), refit and go on trimming
    (at most MAX_IMAGE_ROUNDS times; not after a fit that failed: its residuals accuse nothing).
    refit(data, x0) : a fit of `data` from the full parameter vector x0 (None: the start), with .model, .values,
        .residuals_px and .success: identify's least squares (for a fixed calibration started from its values:
        solver.verify.refit_from). Outliers are decided against this refit, never against fixed values: a corner
        is judged by what no rigid motion of its board explains, and an image by how far the best refit leaves it,
        so a joint, camera or board that moved (which moves whole boards, and which the refit follows) is never
        set aside as a mis-detection.
    homography_rms : {image id: its homography RMS} (solver.image_check), for the report."""
    from naocal.solver.model import Model

    dropped, homography_rms = [], homography_rms or {}
    first_data = data
    result = refit(data, x0)
    outliers, scale, rounds = [], float("nan"), MAX_TRIM_ROUNDS
    kept = np.ones(data.n_rows, dtype=bool)  # of `data`'s rows: the images still in, all their corners
    for image_round in range(MAX_IMAGE_ROUNDS + 1 if robust else 0):
        result, kept, scale, used = _trimmed(result, refit, data, kept, rounds)
        rounds -= used
        outliers = [Outlier(int(data.image_id[data.image_of_row[i]]), int(data.vertex[i]), 0.0)
                    for i in np.flatnonzero(~kept)]
        if image_round == MAX_IMAGE_ROUNDS or not result.success:
            break
        gone = _images_to_set_aside(result, first_data, outliers, homography_rms)
        if not gone:
            break
        ids = {g.image for g in gone}
        dropped += gone
        outliers = [o for o in outliers if o.image not in ids]  # reported as their image
        in_images = ~np.isin(data.image_id[data.image_of_row], list(ids))
        data, kept = without_images(data, ids), kept[in_images]  # subset keeps the rows' order
        result = refit(data.without_rows(np.flatnonzero(~kept)), result.values)
    if outliers:  # their size at the final fit, predicted from the corners that were kept
        kept = without_images(first_data, {g.image for g in dropped})
        original = Model(kept, result.registry).residuals(result.values)
        row = {(int(kept.image_id[m]), int(v)): i for i, (m, v) in enumerate(zip(kept.image_of_row, kept.vertex))}
        for o in outliers:
            o.size_px = float(np.linalg.norm(original[row[(o.image, o.vertex)]]))
    return result.model.data, result, outliers, scale, dropped


@dataclass
class SetAside:
    """What set_aside_mis_detections kept and set aside (robust_fit's results; `images` with the image check's)."""

    data: ModelData  # the corners kept
    fit: object  # the last refit, on `data`
    outliers: list  # [Outlier]: single corners
    robust_scale_px: float
    images: list  # [SetAsideImage]: whole images, the image check's and the fit's

    def describe(self) -> str:
        """The outliers' and the images' lines, as identify prints them."""
        return "\n".join(line for line in (describe_outliers(self.outliers, self.robust_scale_px),
                                            describe_set_aside(self.images)) if line)


def set_aside_mis_detections(data: ModelData, refit, x0=None) -> SetAside:
    """The images no view of a flat board explains (solver.image_check), then robust_fit's corners and images: what
    identify sets aside, for data a caller evaluates under values of its own (verify, the agent's verification)."""
    check = check_images(data)
    data = without_images(data, {s.image for s in check.set_aside}, check)
    kept, fit, outliers, scale, dropped = robust_fit(data, refit, x0, homography_rms=check.rms_px)
    return SetAside(kept, fit, outliers, scale, check.set_aside + dropped)


def _images_to_set_aside(result, first_data: ModelData, outliers, homography_rms) -> list:
    """[SetAsideImage]: the images that lost more than a third of their corners to the trimming, or else the one
    still image the fit leaves far beyond the others (none: [])."""
    ids, n_corners = np.unique(first_data.image_id[first_data.image_of_row], return_counts=True)
    lost = np.bincount(np.searchsorted(ids, np.array([o.image for o in outliers], dtype=np.int64)),
                       minlength=len(ids))
    too_many = lost_too_many(n_corners, lost)
    if too_many.any():
        return [SetAsideImage(int(i), f"lost {k} of {n} corners as mis-detections",
                              homography_rms.get(int(i), float("nan")), int(n), _rms_of(result, first_data, i))
                for i, k, n in zip(ids[too_many], lost[too_many], n_corners[too_many])]
    far = _far_image(result)
    if far is None:
        return []
    image, rms, z = far
    return [SetAsideImage(image, f"its board fits {z:.0f} robust scales worse than the other images' (another "
                                 "board, a shifted lattice or a reflection)",
                          homography_rms.get(image, float("nan")), int(n_corners[ids == image][0]), rms)]


def _far_image(result):
    """(image id, RMS px, scales) of the still image the fit leaves farthest beyond all others, if it is beyond
    IMAGE_SCALES robust scales and IMAGE_MIN_PX (else None)."""
    d, r = result.model.data, result.residuals_px
    rms = np.sqrt(np.bincount(d.image_of_row, (r ** 2).sum(axis=1), d.n_images)
                  / np.maximum(2 * np.bincount(d.image_of_row, minlength=d.n_images), 1))
    still = np.ones(d.n_images, bool) if d.velocity is None else np.all(d.velocity == 0.0, axis=1)
    if still.sum() < MIN_IMAGES_FOR_SCALE:
        return None
    median = float(np.median(rms[still]))
    scale = MAD_TO_SIGMA * float(np.median(np.abs(rms[still] - median)))
    worst = int(np.flatnonzero(still)[np.argmax(rms[still])])
    z = (rms[worst] - median) / scale if scale > 0 else np.inf
    if rms[worst] > IMAGE_MIN_PX and z > IMAGE_SCALES:
        return int(d.image_id[worst]), float(rms[worst]), float(z)
    return None


def _rms_of(result, data: ModelData, image_id) -> float:
    """RMS (both coordinates) of one image's corners, all of them, at `result`'s values."""
    from naocal.solver.model import Model

    m = int(np.flatnonzero(data.image_id == image_id)[0])
    r = Model(data.subset([m]), result.registry).residuals(result.values)
    return float(np.sqrt(np.mean(r ** 2)))


def _trimmed(result, refit, data: ModelData, kept, rounds: int):
    """(result, kept, robust scale, rounds used): solver.identify.trimmed on the corners of `data` (`result` the fit
    of its rows `kept`): a corner is judged by its non-rigid residual (what no rigid motion of its board explains,
    the motion fitted to the board's kept corners) against max(OUTLIER_SCALES robust scales, OUTLIER_MIN_PX); the
    worst of each image per round; those the final fit explains taken back."""
    from naocal.solver.model import Model
    from naocal.solver.noisefloor import RigidSplit

    scale = [float("nan")]

    def judge(result, kept):
        model = Model(data, result.registry)
        nonrigid = RigidSplit(model, result.values, kept)(model.residuals(result.values))[1]
        scale[0] = MAD_TO_SIGMA * float(np.median(np.abs(nonrigid[kept])))
        return np.linalg.norm(nonrigid, axis=1), max(OUTLIER_SCALES * scale[0], OUTLIER_MIN_PX)

    def refit_kept(kept, result):
        return refit(data.without_rows(np.flatnonzero(~kept)), result.values)

    result, kept, used = trimmed(result, refit_kept, judge, data.image_of_row, kept, rounds=rounds)
    return result, kept, scale[0], used


def _flagged(fits) -> tuple[set, set]:
    """The corners (image, vertex) and the whole images any hypothesis set aside."""
    return ({(o.image, o.vertex) for f in fits.values() for o in f[2]},
            {s.image for f in fits.values() for s in f[4]})


def _rms_without(result, flagged, images=frozenset()) -> float:
    """RMS over both coordinates of a hypothesis's fit, on the corners no hypothesis flagged and outside the images
    any set aside (a fair comparison)."""
    d = result.model.data
    keep = np.array([(int(d.image_id[m]), int(v)) not in flagged and int(d.image_id[m]) not in images
                     for m, v in zip(d.image_of_row, d.vertex)], dtype=bool)
    r = result.residuals_px[keep]
    return float(np.sqrt(np.mean(r ** 2))) if r.size else float("nan")


def choose_angles(fits) -> tuple[str, list[AngleHypothesis]]:
    """(the hypothesis chosen, [AngleHypothesis]) from {mode: robust_fit's (data, fit, outliers, scale, images, ...)}:
    each compared on the corners none set aside; a later one in ANGLE_HYPOTHESES must be clearly better."""
    flagged = _flagged(fits)
    hypotheses = [AngleHypothesis(mode, _rms_without(f[1], *flagged), len(f[2])) for mode, f in fits.items()]
    best = None
    for h in hypotheses:
        if best is None or h.rms_px < best.rms_px * (1.0 - ANGLE_MARGIN):
            best = h
    return best.mode, hypotheses
