"""Pairs of mechanisms as contenders: the base model plus two candidates at once (rolling resistance
and side-wall friction, say), fitted in the DEM and scored on the diagnosis' own terms, so that
calibration.contenders can set them beside the single mechanisms.

The diagnosis adds one candidate at a time; a pair has no design runs of its own. So a pair is
fitted where the diagnosis left its better member: that member's DEM-scored fit, the other
mechanism off (Model.embed), then the measured curve's own Gauss-Newton steps in the DEM along
slopes measured by a star design about that start (calibration.target_scale.star_points,
calibration.confirmation.refine with the secant update), all at the diagnosis' grain size on the
confirmation packings. The lowest point is then run on the packings of its member's DEM score and
scored against the same noise std and number of data (DEMScore.sigma, n_data): chi^2 of the mean of
those runs, and BIC = chi^2 + p ln n with the pair's p = 4. The extra parameter costs ln n, so a
pair that only reproduces its member scores worse than it; it wins only where both mechanisms
together fit the curve, or predict across a, better than either alone.

Cost per pair: (2p + 1 + rounds) x packings runs (9 + 3 = 12 x 4 = 48 at p = 4) plus the BIC's
(the diagnosis' packings, 2 by default), at the diagnosis' grain size.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from calibration.calibrated import CalibrationError
from calibration.design_runs import DEMRunner, SimulationSettings
from calibration.diagnosis_result import Diagnosis
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.observables import Observables
from calibration.scoring import bic
from calibration.target_scale import run_star, secant_steps, star_points
from dem.engines import FAILURES
from dem.runout import RunoutMethod


@dataclass
class PairFit:
    """A pair's DEM fit to the measured curve and its score on the diagnosis' terms.

    start: the single mechanism whose fit it started from; start_mse: that fit's runout MSE (mean
    curve) on the confirmation packings; parameters {name: value}: the lowest point there; fit_mse:
    its runout MSE there; chi2, bic: on
    the packings of the start's DEM score (packings, their indices into the diagnosis' packing
    seeds), against its noise std; dem_runs, seconds: everything the fit and the score ran."""

    start: str
    start_mse: float
    parameters: dict[str, float]
    fit_mse: float
    chi2: float
    bic: float
    packings: list[int]
    dem_runs: int
    seconds: float


def diagnosis_simulation(diagnosis: Diagnosis) -> SimulationSettings:
    """The DEM settings the diagnosis ran with (its grains, packing seeds and settling reference)."""
    settings = diagnosis.settings
    return SimulationSettings(
        size_scale=float(settings["size_scale"]),
        packing_seeds=tuple(int(s) for s in settings["packing_seeds"]),
        reference=tuple(float(v) for v in settings["reference"]),
    )


def fit_pair(
    pair: Model,
    start: Model,
    start_theta: Sequence[float],
    diagnosis: Diagnosis,
    column: MeasuredColumn,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_packings: int = 4,
    n_rounds: int = 3,
    progress: Callable[[float], None] | None = None,
) -> PairFit:
    """`pair` fitted to `column` from `start` (a model of one of its mechanisms) at start_theta [q],
    its DEM-scored fit in `diagnosis` (module docstring). CalibrationError where the diagnosis did
    not score `start` in the DEM or observed other data than `column`."""
    started = time.perf_counter()
    evidence = diagnosis.candidates.get(start.name)
    if evidence is None or evidence.dem is None:
        raise CalibrationError(f"{pair.name}: the diagnosis did not score {start.name} in the DEM, so no start")
    settings = diagnosis_simulation(diagnosis)
    points = star_points(pair, pair.embed(start, start_theta))
    total = (len(points) + n_rounds) * n_packings + len(evidence.dem.packings)

    def part(offset: float, width: float) -> Callable[[float], None] | None:
        return None if progress is None else (lambda f: progress(min((offset + f * width) / total, 1.0)))

    label = f"{pair.name} star point {{k}}"
    slopes = run_star(pair, column, points, settings, runout, dem_config, n_packings, label, part)
    within = part(len(points) * n_packings, n_rounds * n_packings)
    correction = secant_steps(pair, column, slopes[0], points, slopes, settings, runout, dem_config, n_rounds, within)
    chosen = correction.checked[correction.chosen]
    theta = [chosen.parameters[name] for name in pair.parameter_names]
    within = part(total - len(evidence.dem.packings), len(evidence.dem.packings))
    chi2, packings = diagnosis_chi2(pair, theta, diagnosis, start.name, column, settings, runout, within)
    n_data = evidence.dem.n_data
    return PairFit(
        start=start.name,
        start_mse=float(slopes[0].mse),
        parameters=dict(zip(pair.parameter_names, map(float, theta))),
        fit_mse=float(chosen.mse),
        chi2=chi2,
        bic=bic(chi2, pair.n_parameters, n_data) if math.isfinite(chi2) else math.inf,
        packings=packings,
        dem_runs=sum(len(v.seeds) for v in slopes) + correction.dem_runs - len(slopes[0].seeds) + len(packings),
        seconds=time.perf_counter() - started,
    )


def diagnosis_chi2(
    model: Model,
    theta: Sequence[float],
    diagnosis: Diagnosis,
    reference: str,
    column: MeasuredColumn,
    settings: SimulationSettings,
    runout: RunoutMethod,
    progress: Callable[[float], None] | None = None,
) -> tuple[float, list[int]]:
    """(chi^2, packings that ran) of `model` at theta [p] on the diagnosis' terms: the mean
    observables of runs on the packings of candidate `reference`'s DEM score against the measured
    data, in units of that score's noise std. inf where no run ran."""
    score = diagnosis.candidates[reference].dem
    observables = Observables([column], runout)
    measured = np.asarray(diagnosis.observables.measured, float)
    if observables.measured.shape != measured.shape or not np.allclose(observables.measured, measured):
        raise CalibrationError(
            f"{column.name}: the diagnosis observed other data ({len(measured)} values) than this column "
            f"({len(observables.measured)}); rerun the diagnosis"
        )
    runner = DEMRunner(observables, settings)
    observed, ran = [], []
    for k, packing in enumerate(score.packings):
        try:
            observed.append(runner.observe(model, theta, packing))
            ran.append(int(packing))
        except FAILURES:  # a run that failed is in no mean
            pass
        if progress is not None:
            progress((k + 1) / len(score.packings))
    if not observed or len(ran) != len(score.packings):  # sigma is that of a mean of as many runs
        return math.inf, ran
    mean = np.mean(observed, axis=0)
    return float(np.sum(((mean - measured) / np.asarray(score.sigma, float)) ** 2)), ran
