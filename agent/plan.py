"""A measurement plan: what the agent captures, in which order. Data only; `agent.planner` makes plans.

A plan is a list of steps. A `Still` step is one image of a resting robot; a `Sweep` step (the lag probe) moves
one leg slowly and continuously through a visible stance and takes several images on the way. Every image has its
dataset index (`image`) fixed by the plan, so an interrupted run resumes exactly where it stopped: captures already
in the dataset are skipped, nothing is captured twice. Angles are 14-vectors in solver.joints.JOINTS order, rad.

The plan is stored as `plan.json` (schema `naocal.plan/1`) beside the dataset.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from naocal.solver.dataset import parse_json_text, read_text
from naocal.solver.errors import DataError
from naocal.solver.fileio import atomic_write_text
from naocal.solver.joints import JOINTS

SCHEMA = "naocal.plan/1"


@dataclass(frozen=True)
class Still:
    """One image of the robot at rest at `angles_rad`."""

    image: int
    leg: str
    stance: int
    head_posture: int
    angles_rad: tuple  # 14 floats
    camera: str = "bottom"  # the camera the image is taken with

    @property
    def images(self) -> tuple[int, ...]:
        return (self.image,)

    def angles(self) -> np.ndarray:
        return np.array(self.angles_rad, dtype=float)


@dataclass(frozen=True)
class Sweep:
    """The lag probe: from rest at `start_rad`, move to `end_rad` at `speed_fraction` and take one image at each of
    `exposure_fractions` of the motion's duration; image k gets dataset index `images[k]`."""

    images: tuple
    leg: str
    stance: int
    start_rad: tuple
    end_rad: tuple
    speed_fraction: float
    exposure_fractions: tuple

    def start(self) -> np.ndarray:
        return np.array(self.start_rad, dtype=float)

    def end(self) -> np.ndarray:
        return np.array(self.end_rad, dtype=float)


@dataclass
class Plan:
    """Everything the measurement needs, deterministic from (seed, settings)."""

    seed: int
    kind: str  # "paper" or "optimal"
    settings: dict
    steps: list  # [Still | Sweep] in execution order
    verification: list  # [Still]: held-out stances re-measured after compensation (image = their own count)
    parked_rad: tuple  # 14 angles: both legs out of the way, head resting (the transit posture)
    stats: dict = field(default_factory=dict)  # what the planner reports about the plan (precision, time, ...)

    def image_indices(self) -> list[int]:
        return [i for step in self.steps for i in step.images]

    def n_images(self) -> int:
        return len(self.image_indices())

    def stills(self) -> list[Still]:
        return [s for s in self.steps if isinstance(s, Still)]

    def sweeps(self) -> list[Sweep]:
        return [s for s in self.steps if isinstance(s, Sweep)]

    def parked(self) -> np.ndarray:
        return np.array(self.parked_rad, dtype=float)

    # --- JSON ---------------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        def still(s: Still) -> dict:
            return {"kind": "still", "image": s.image, "leg": s.leg, "stance": s.stance,
                    "head_posture": s.head_posture, "angles_rad": [float(a) for a in s.angles_rad],
                    "camera": s.camera}

        def step(s) -> dict:
            if isinstance(s, Still):
                return still(s)
            return {"kind": "sweep", "images": list(s.images), "leg": s.leg, "stance": s.stance,
                    "start_rad": [float(a) for a in s.start_rad], "end_rad": [float(a) for a in s.end_rad],
                    "speed_fraction": float(s.speed_fraction),
                    "exposure_fractions": [float(f) for f in s.exposure_fractions]}

        return {"schema": SCHEMA, "seed": self.seed, "kind": self.kind, "joints": list(JOINTS),
                "settings": self.settings, "parked_rad": [float(a) for a in self.parked_rad],
                "steps": [step(s) for s in self.steps], "verification": [still(s) for s in self.verification],
                "stats": self.stats}

    @classmethod
    def from_dict(cls, doc, path="<plan>") -> "Plan":
        try:
            if doc.get("schema") != SCHEMA:
                raise DataError(path, f"wrong schema {doc.get('schema')!r}, expected {SCHEMA!r}", field="schema")
            if doc.get("joints") != list(JOINTS):
                raise DataError(path, "joint order differs from this naocal's", field="joints")

            def angles(values, where):
                if len(values) != len(JOINTS) or not all(np.isfinite(values)):
                    raise DataError(path, f"expected {len(JOINTS)} finite angles", field=where)
                return tuple(float(a) for a in values)

            def still(d, where):
                camera = d.get("camera", "bottom")  # plans from before the top camera have none
                if camera not in ("bottom", "top"):
                    raise DataError(path, f"unknown camera {camera!r} (expected bottom or top)", field=f"{where}.camera")
                return Still(int(d["image"]), str(d["leg"]), int(d["stance"]), int(d["head_posture"]),
                             angles(d["angles_rad"], f"{where}.angles_rad"), camera)

            steps = []
            for k, d in enumerate(doc["steps"]):
                where = f"steps[{k}]"
                if d["kind"] == "still":
                    steps.append(still(d, where))
                elif d["kind"] == "sweep":
                    steps.append(Sweep(tuple(int(i) for i in d["images"]), str(d["leg"]), int(d["stance"]),
                                       angles(d["start_rad"], f"{where}.start_rad"),
                                       angles(d["end_rad"], f"{where}.end_rad"), float(d["speed_fraction"]),
                                       tuple(float(f) for f in d["exposure_fractions"])))
                else:
                    raise DataError(path, f"unknown step kind {d['kind']!r}", field=f"{where}.kind")
            verification = [still(d, f"verification[{k}]") for k, d in enumerate(doc["verification"])]
            return cls(int(doc["seed"]), str(doc["kind"]), dict(doc["settings"]), steps, verification,
                       angles(doc["parked_rad"], "parked_rad"), dict(doc.get("stats", {})))
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise DataError(path, f"malformed plan ({type(err).__name__}: {err})") from None


def write_plan(plan: Plan, path) -> Path:
    return atomic_write_text(path, json.dumps(plan.to_dict(), indent=1, allow_nan=False) + "\n")


def read_plan(path) -> Plan:
    return Plan.from_dict(parse_json_text(read_text(path), path), path)
