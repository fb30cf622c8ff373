"""What an engineer does next with the calibrated model: predict columns of other aspect ratios
(same material, L_i and scale as the measured column), their final runout and deposit height,
one DEM run each, to set beside the measured column and the experimental scaling law.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from calibration.calibrated import VALIDATION_SEED0, buildable_cases
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from dem.engines import FAILURES, failure_reason, simulate_case
from dem.run_ahead import run_ahead
from dem.runout import RunoutMethod, final_height

log = logging.getLogger(__name__)

PREDICTION_TSTAR = 6.0  # simulated t/t* of a prediction: long enough for the front to stop


@dataclass
class Prediction:
    """Final state of the calibrated model's collapse per aspect ratio (one packing each):
    final_runout [A] = L* at PREDICTION_TSTAR, final_height [A] (m) of the connected deposit, and
    H_f / L_i; None where the run failed (`failed` says why)."""

    aspect_ratios: list[float]
    final_runout: list[float | None]
    final_height: list[float | None]
    height_over_L_i: list[float | None]
    failed: dict[str, str]
    seed: int
    seconds: float

    def to_dict(self) -> dict:
        return asdict(self)


def predicted_column(column: MeasuredColumn, aspect_ratio: float) -> MeasuredColumn:
    """`column` at another aspect ratio, read at t/t* = PREDICTION_TSTAR only, with nothing measured."""
    return replace(
        column,
        name=f"{column.name}_a{aspect_ratio:g}",
        aspect_ratio=float(aspect_ratio),
        t_over_tstar=np.array([PREDICTION_TSTAR]),
        runout=np.array([math.nan]),
        runout_std=None,
        profile_x=None,
        profile_height=None,
        profile_std=None,
    )


def predict(
    model: Model,
    column: MeasuredColumn,
    theta: Sequence[float],
    settings: SimulationSettings,
    aspect_ratios: Sequence[float],
    runout: RunoutMethod,
    dem_config: dict | None,
    seed: int = VALIDATION_SEED0,
    progress: Callable[[float], None] | None = None,
) -> Prediction:
    """The model at theta [p] on columns of `column`'s material and L_i at each aspect ratio,
    simulated to t/t* = PREDICTION_TSTAR on packing `seed`, the runout read as `column`'s (its stated
    method, else `runout`). progress: callable(fraction of the columns done) or None."""
    started = time.perf_counter()
    others = [predicted_column(column, a) for a in aspect_ratios]
    run_ahead(
        [case for other in others for case in buildable_cases(model, other, [theta], settings, [seed])],
        dem_config,
        f"predictions at a = {', '.join(f'{a:g}' for a in aspect_ratios)}",
    )
    runouts, heights, failed = [], [], {}
    for k, (a, other) in enumerate(zip(aspect_ratios, others)):
        try:
            within = None if progress is None else (lambda f, k=k: progress((k + f) / len(aspect_ratios)))
            trajectory = simulate_case(model.case(other, theta, settings, seed), dem_config, progress=within)
            runouts.append(float(column.runout_reading(runout).curve(trajectory)[1][-1]))
            heights.append(final_height(trajectory.positions[-1], trajectory.radius))
        except FAILURES as exc:
            log.warning("prediction at a = %g failed: %s", a, exc)
            failed[f"{a:g}"] = failure_reason(exc)
            runouts.append(None)
            heights.append(None)
    return Prediction(
        aspect_ratios=[float(a) for a in aspect_ratios],
        final_runout=runouts,
        final_height=heights,
        height_over_L_i=[None if h is None else h / column.L_i for h in heights],
        failed=failed,
        seed=seed,
        seconds=time.perf_counter() - started,
    )
