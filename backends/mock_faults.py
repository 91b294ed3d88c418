"""The corner detector's real failure modes, for the realistic mock: a post-detection fault model.

On real images a checkerboard detector now and then reports a corner a square off (it locked onto the neighbouring
X-corner) or somewhere near it (a reflection, a scratch, a fold of the print pulled the refinement away). The mock's
rendered boards are clean, so the mock injects these faults after detection: `FaultyDetector(detector, rate, seed)`
wraps any detector (agent.measure's signature) and moves each detected vertex, with probability `rate`, either
onto a neighbouring vertex's detected position (a square off, half the faults) or by 3-20 px in a random
direction (a reflection, the other half). Which vertices, and how, follows from the seed, the image's time stamp
and the leg, so a run is reproducible and a retried capture gets new draws.

Why after detection and not in the pixels: the faults the solver must survive are wrong corners that pass the
detector's own checks; a rendered reflection mostly makes the detector refuse the board (the mock renders glare
spots too, `Realism.glare_rate`). The faults live with the agent's detector, so `naocal calibrate --backend mock
--mock realistic` applies them; a mock served over the bridge renders glare but cannot touch the agent's detections.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from naocal.solver.nao_model import BOARD_COLUMNS

SHIFT_RANGE_PX = (3.0, 20.0)
GRID_COLUMNS = BOARD_COLUMNS - 1  # vertices per row (index = row * 6 + col)


@dataclass(frozen=True)
class CornerFault:
    vertex: int
    kind: str  # "square" (a neighbour's position) or "reflection" (moved 3-20 px)
    shift_px: tuple


def draw_faults(rng, vertices_px: np.ndarray, rate: float) -> tuple[np.ndarray, list[CornerFault]]:
    """(moved copy of vertices_px (24, 2), the faults drawn). Each vertex is faulty with probability `rate`."""
    out = np.array(vertices_px, dtype=float)
    n = len(out)
    faulty = np.flatnonzero(rng.uniform(size=n) < rate)
    faults = []
    for i in faulty:
        row, col = divmod(int(i), GRID_COLUMNS)
        neighbours = [r * GRID_COLUMNS + c for r, c in ((row - 1, col), (row + 1, col), (row, col - 1), (row, col + 1))
                      if 0 <= r < n // GRID_COLUMNS and 0 <= c < GRID_COLUMNS]
        if rng.uniform() < 0.5:
            target = vertices_px[neighbours[int(rng.integers(len(neighbours)))]]
            shift = np.asarray(target, dtype=float) - vertices_px[i]
            kind = "square"
        else:
            angle = rng.uniform(0.0, 2.0 * np.pi)
            shift = rng.uniform(*SHIFT_RANGE_PX) * np.array([np.cos(angle), np.sin(angle)])
            kind = "reflection"
        out[i] = vertices_px[i] + shift
        faults.append(CornerFault(int(i), kind, (float(shift[0]), float(shift[1]))))
    return out, faults


class FaultyDetector:
    """A detector whose successful detections carry the fault model's wrong corners (module docstring).

    `faults` keeps every fault injected, as (image stamp, leg, CornerFault), for tests and the summary.
    """

    def __init__(self, detector, rate: float, seed: int):
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"corner fault rate must be within 0..1, got {rate}")
        self.detector = detector
        self.rate = float(rate)
        self.seed = int(seed)
        self.faults: list = []
        self.n_vertices = 0

    def __call__(self, image, predicted_px, leg, search_margin_px):
        found = self.detector(image, predicted_px, leg, search_margin_px)
        if not found.ok or self.rate == 0.0:
            return found
        stamp_us = int(round(float(image.t_exposure_s) * 1e6))
        rng = np.random.default_rng([self.seed, 7727, stamp_us, 0 if leg == "L" else 1])
        moved, faults = draw_faults(rng, found.vertices_px, self.rate)
        self.n_vertices += len(moved)
        self.faults += [(float(image.t_exposure_s), leg, f) for f in faults]
        if not faults:
            return found
        return dataclasses.replace(found, vertices_px=moved)
