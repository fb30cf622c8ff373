"""A surrogate's optimum confirmed by the DEM: the best few distinct points a GNS search found, each
run by the DEM on packings of their own, and the one the DEM scores lowest kept.

Near its optimum a GNS objective is flat within the GNS's own error, so which of its near-best
points a search returns depends on the bits of the GNS (its training seed, the CPU's torch
kernels), and those points can lie far apart in the parameters. A point the GNS likes but the DEM
does not is then the route's answer. Running the few best distinct points through the DEM first,
on packings no calibration, validation or runoff uses (CONFIRM_SEED0 + k), lets the DEM choose
among them; the chosen point is then validated like every route's, on the validation packings, so
the choice does not flatter its validated score. Cost: candidates x packings DEM runs, counted
with the route's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from calibration.calibrated import CalibrationError, Validation, validate
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.sensitivity import finite_or_none
from dem.runout import RunoutMethod

CONFIRM_SEED0 = 7001  # confirmation packings: no calibration's, validation's (5001...) or diagnosis' seed
MIN_UNIT_DISTANCE = 0.1  # candidates this far apart at least, in the model's unit box (log axes where it has them)


@dataclass
class Confirmation:
    """The DEM's check of a surrogate's best points.

    candidates [n]: each point's Validation on the confirmation packings (seeds CONFIRM_SEED0 + k),
    its route naming its rank; surrogate_values [n]: the surrogate's objective at each; chosen: the
    index of the lowest DEM MSE (the surrogate's best where every run failed)."""

    candidates: list[Validation]
    surrogate_values: list[float]
    chosen: int

    @property
    def dem_runs(self) -> int:
        """The DEM runs made: candidates x packings, a failed run counted too."""
        return sum(len(c.seeds) for c in self.candidates)

    @property
    def theta(self) -> list[float]:
        """The chosen point's parameters [p], in the model's order."""
        return list(self.candidates[self.chosen].parameters.values())

    def to_dict(self) -> dict:
        """JSON: per candidate its parameters, seeds, curves [R][K] (None where a run failed), failed
        {seed: reason}, mse of the mean curve and mse_each [R] (None where not finite)."""
        return {
            "candidates": [
                {
                    "parameters": c.parameters,
                    "seeds": c.seeds,
                    "curves": c.curves,
                    "failed": c.failed,
                    "mse": finite_or_none(c.mse),
                    "mse_each": [finite_or_none(v) for v in c.mse_each],
                }
                for c in self.candidates
            ],
            "surrogate_values": self.surrogate_values,
            "chosen": self.chosen,
            "dem_runs": self.dem_runs,
        }


def distinct_best(
    points: np.ndarray, values: np.ndarray, model: Model, n: int, min_distance: float = MIN_UNIT_DISTANCE
) -> list[int]:
    """Indices of up to n points [m, p] of lowest finite `values` [m], each at least min_distance
    (Euclidean, in the model's unit box) from every lower-valued one kept: the best point first."""
    finite = np.flatnonzero(np.isfinite(values))
    order = finite[np.argsort(values[finite], kind="stable")]
    unit = model.box.to_unit(np.asarray(points, float))
    kept: list[int] = []
    for index in order:
        if all(np.linalg.norm(unit[index] - unit[k]) >= min_distance for k in kept):
            kept.append(int(index))
            if len(kept) == n:
                break
    return kept


def confirm(
    model: Model,
    column: MeasuredColumn,
    points: Sequence[Sequence[float]],
    values: Sequence[float],
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_candidates: int = 3,
    n_packings: int = 2,
    progress: Callable[[float], None] | None = None,
) -> Confirmation:
    """The n_candidates distinct best (distinct_best) of a surrogate's evaluated `points` [m, p]
    (values [m]: its objective there, NaN where it failed) run by the DEM on n_packings packings of
    their own; the one whose mean curve has the lowest runout MSE is chosen."""
    points, values = np.asarray(points, float), np.asarray(values, float)
    picked = distinct_best(points, values, model, n_candidates)
    if not picked:
        raise CalibrationError(f"{column.name}: no finite surrogate value among {len(values)} points to confirm")
    candidates = []
    for rank, index in enumerate(picked):
        within = None if progress is None else (lambda f, rank=rank: progress((rank + f) / len(picked)))
        theta, label = points[index], f"candidate {rank + 1}"
        own = {"progress": within, "seed0": CONFIRM_SEED0}
        candidates.append(validate(label, model, column, theta, settings, runout, dem_config, n_packings, **own))
    scores = [c.mse if math.isfinite(c.mse) else math.inf for c in candidates]
    chosen = int(np.argmin(scores)) if math.isfinite(min(scores)) else 0
    return Confirmation(candidates, [float(values[i]) for i in picked], chosen)
