"""The calibrated model an engineer takes away: which model (the paper's base model, or the base
model plus the mechanism the diagnosis named), its parameters, and how well DEM runs at them
reproduce the measurement, judged on several packings against their own scatter.

Model (`resolve_model`): the config's choice, or `auto`: the diagnosis' cause, else its best
candidate, with how decisive the evidence was.

Routes to the parameters, each ending in the same validation:
- the diagnosis' own calibration of that model (an emulator of its design runs, checked in DEM);
- Bayesian optimisation on DEM runs of the measured column (one packing, seed CALIBRATION_SEED +
  calibration.seed).

Validation (`validate`): DEM runs at the parameters on packings the calibration never saw
(VALIDATION_SEED0, +1, ...); the score is the runout MSE of their mean curve against the
measurement, beside each packing's own MSE and the packing scatter. A run that fails (blows up,
an engine error) is reported with its packing and never averaged in. The same validation one
size_scale finer says how far the answer transfers (`validate` with finer settings).

Which route is the answer: calibration/answer_choice.py (the routes not told apart from the best
run on more packings, and the lowest there answers).

What the answer predicts for columns of other aspect ratios: calibration/prediction.py.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calibration.bayesopt import BOSettings, bayesian_optimisation
from calibration.design_runs import SimulationSettings
from calibration.diagnosis_result import Diagnosis
from calibration.emulator import latin_hypercube
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import BASE_BOUNDS, MechanismError, candidate_mechanisms
from calibration.model import Model, model_named
from calibration.objective import runout_mse, simulated_runout_at
from calibration.optimise import OptimisationHistory, PointFailed, one_at_a_time
from dem.case import CollapseCase
from dem.engines import FAILURES, failure_reason, simulate_case
from dem.grid import case_id_of
from dem.run_ahead import run_ahead
from dem.runout import RunoutMethod

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

log = logging.getLogger(__name__)

MODELS = ("auto", "base") + tuple(candidate_mechanisms())  # and pairs of mechanisms, "a+b" (model_named)
CALIBRATION_SEED = 0  # the packing the Bayesian optimisation runs on
VALIDATION_SEED0 = 5001  # validation packings: never a calibration's, a diagnosis' or a hidden truth's


class CalibrationError(ValueError):
    """The calibrated model cannot be set up; the message names the key or the file."""


# -- which model --------------------------------------------------------------------------------
def resolve_model(choice: str, diagnosis: Diagnosis | None, channel_width: float = 0.01) -> tuple[Model, str]:
    """(Model, why it was chosen). choice: `base`, a candidate mechanism's name, two joined by "+"
    (a pair), or `auto` (the diagnosis' cause, else its best candidate: `diagnosis` is then required)."""
    if choice not in MODELS:
        try:
            model = model_named(choice, channel_width)
        except MechanismError as exc:
            raise CalibrationError(
                f"calibration.model: unknown model {choice!r} ({exc}); choose one of {list(MODELS)} "
                "or a pair of mechanisms joined by '+'"
            ) from None
        return model, f"the config asks for the base model + {' + '.join(m.name for m in model.mechanisms)}"
    if choice == "base":
        return Model(), "the config asks for the base model (mu, e)"
    if choice != "auto":
        return model_named(choice, channel_width), f"the config asks for the base model + {choice}"
    if diagnosis is None:
        raise CalibrationError("calibration.model: auto needs the diagnosis of this column (diagnosis.enabled)")
    if diagnosis.cause != "none":
        return (
            model_named(diagnosis.cause, channel_width),
            f"auto: the diagnosis named {diagnosis.cause} (every check of its decision rule passed). "
            + diagnosis.verdict,
        )
    failed = [name for name, passed in diagnosis.checks.items() if not passed]
    best = diagnosis.best_candidate
    return (
        model_named(best, channel_width),
        f"auto: the diagnosis named no cause ({', '.join(failed)} failed), so its best candidate, {best}, is "
        f"calibrated: weaker evidence than a named cause. {diagnosis.verdict}",
    )


BOX_WIDENING = 2.0  # the calibration box: the diagnosis' 95% interval of the mechanism, this many times as wide ...
BOX_MIN_FRACTION = 0.25  # ... and at least this fraction of the candidate's whole range


def calibration_box(model: Model, diagnosis: Diagnosis | None, box: str = "diagnosis") -> Model:
    """The model with the range its mechanism's parameter is calibrated in: box "full" (the
    candidate's whole range, calibration/mechanisms.py) or "diagnosis": centred on the diagnosis'
    estimate, BOX_WIDENING times its 95% interval and at least BOX_MIN_FRACTION of the whole range,
    inside it. Every route (GNS dataset, DoE, BO) then spends its runs where the measurement puts
    the parameter instead of across magnitudes the diagnosis has ruled out; a parameter the
    diagnosis could not pin down (not identifiable) keeps the whole range, and so does each
    parameter of a pair, which the diagnosis (one mechanism at a time) never fitted."""
    if box not in ("diagnosis", "full"):
        raise CalibrationError(f"calibration.box: unknown box {box!r}; choose diagnosis or full")
    if len(model.mechanisms) != 1 or box == "full" or diagnosis is None:
        return model
    mechanism = model.mechanism
    estimate = diagnosis_parameters(diagnosis, model)[-1]
    (interval,) = [
        p for p in diagnosis.candidates[model.name].emulator.posterior.parameters if p.name == mechanism.parameter
    ]
    if not interval.identifiable:
        return model
    low, high = mechanism.bounds
    half = max(BOX_WIDENING * 0.5 * (interval.high - interval.low), BOX_MIN_FRACTION * 0.5 * (high - low))
    half = min(half, 0.5 * (high - low))
    centre = min(max(estimate, low + half), high - half)  # the box slides inside the whole range
    return Model(replace(mechanism, bounds=(float(centre - half), float(centre + half))))


def model_record(model: Model, why: str, name: str = "") -> dict:
    """model.json: the model one measured column is calibrated as (the DAG's answer to `auto`)."""
    return {
        "name": name,
        "model": model.name,
        "parameters": list(model.parameter_names),
        "bounds": model.bounds.tolist(),
        "log_scale": [bool(v) for v in model.box.log_scale],
        "why": why,
        # each mechanism parameter's physically plausible range for the column's material, and its source
        "plausible": [list(m.plausible) for m in model.mechanisms],
        "plausible_source": [m.plausible_source for m in model.mechanisms],
    }


def read_model(path: str | os.PathLike, channel_width: float = 0.01) -> tuple[Model, str]:
    """(Model, why) from a model.json written with model_record; CalibrationError naming the file
    when it is not one."""
    try:
        record = json.loads(Path(path).read_text())
        choice = record["model"]
        model = model_named(choice, channel_width)
        bounds = [tuple(map(float, b)) for b in record["bounds"]]
        plausible = [tuple(map(float, r)) for r in record.get("plausible") or []]
        sources = list(record.get("plausible_source") or [])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CalibrationError(f"{path}: not a calibrated-model file ({type(exc).__name__}: {exc})") from exc
    if list(model.parameter_names) != list(record.get("parameters", [])):
        raise CalibrationError(
            f"{path}: parameters {record.get('parameters')} differ from model {choice}'s {list(model.parameter_names)}"
        )
    if plausible and (len(plausible) != len(model.mechanisms) or len(sources) != len(plausible)):
        raise CalibrationError(f"{path}: plausible ranges {record['plausible']} are not one per mechanism of {choice}")
    mechanisms = []
    for k, mechanism in enumerate(model.mechanisms):  # the calibration box of each, inside its whole range
        (low, high), (whole_low, whole_high) = bounds[len(BASE_BOUNDS) + k], mechanism.bounds
        if not whole_low <= low < high <= whole_high:
            raise CalibrationError(
                f"{path}: {mechanism.parameter} range [{low:g}, {high:g}] is not inside its whole range "
                f"[{whole_low:g}, {whole_high:g}]"
            )
        mechanism = replace(mechanism, bounds=(low, high))
        if plausible:  # stated for the column's material (calibration.plausible_ranges)
            mechanism = replace(mechanism, plausible=plausible[k], plausible_source=str(sources[k]))
        mechanisms.append(mechanism)
    if bounds[: len(BASE_BOUNDS)] != list(BASE_BOUNDS):
        raise CalibrationError(f"{path}: bounds of friction and restitution {bounds[:2]} are not {list(BASE_BOUNDS)}")
    return Model(*mechanisms), str(record.get("why", ""))


def diagnosis_parameters(diagnosis: Diagnosis, model: Model) -> np.ndarray:
    """theta [p] the diagnosis calibrated `model` to: its DEM-scored optimum where it has one, else
    its emulator's. CalibrationError for a model the diagnosis did not fit (a pair)."""
    evidence = diagnosis.base if model.name == "base" else diagnosis.candidates.get(model.name)
    if evidence is None:
        raise CalibrationError(f"the diagnosis fitted no model {model.name!r} (it fits one mechanism at a time)")
    parameters = evidence.dem.parameters if evidence.dem is not None else evidence.emulator.parameters
    return np.array([parameters[name] for name in model.parameter_names], float)


# -- the GNS dataset of the model -------------------------------------------------------------------
DATASET_SEED0 = 3001  # packings of the model's GNS dataset: never a validation's (VALIDATION_SEED0)


@dataclass(frozen=True)
class DatasetCase:
    """One DEM case of the model's GNS dataset: parameters {name: value} of the model."""

    case_id: str
    parameters: dict
    case: CollapseCase


def model_dataset_cases(model: Model, template: CollapseCase, n_cases: int, seed: int) -> list[DatasetCase]:
    """The GNS dataset of `model` on the column of `template` (a case of the base model's GNS dataset
    of the measured column: its geometry, grain scale, frame interval and duration): n_cases seeded
    Latin-hypercube points over model.box, each on its own packing (DATASET_SEED0 + k), in the order
    of the model's last parameter (the mechanism's). The splits are the case order's
    (dem.grid.assign_splits; pipeline.calibrated_gns.case_splits): known before the model is."""
    if n_cases < 3:
        raise CalibrationError(f"calibration.gns_cases: {n_cases} cases cannot fill train, valid and test")
    theta = latin_hypercube(model.box, n_cases, seed)
    # in the order of the mechanism's parameter: the valid and test splits, spread along the order,
    # then span its range (a random order once put every valid case at weak cohesion)
    theta = theta[np.argsort(theta[:, -1], kind="stable")]
    cases = []
    for k, point in enumerate(theta):
        case_id = case_id_of(k, n_cases)
        name = f"{template.name.split('/')[0]}:{model.name}/{case_id}"
        case = model.at(template.replace(seed=DATASET_SEED0 + k, name=name), point)
        cases.append(DatasetCase(case_id, dict(zip(model.parameter_names, map(float, point))), case))
    return cases


# -- DEM runs of the model ------------------------------------------------------------------------
@dataclass
class Validation:
    """DEM runs of a model at `parameters` on several packings, against the measured runout.

    t_over_tstar [K]: the measured times; curves [R][K]: L* of each packing that ran (None where it
    failed, `failed` says why); mean [K] and std [K] over the runs that ran; mse: the runout MSE of
    the mean curve (NaN when none ran); mse_each [R]: each run's own MSE (NaN where it failed);
    mse_se: the jackknife standard error of mse over the packings (mse_jackknife): how much another
    set of as many packings could move it.
    """

    route: str
    parameters: dict
    seeds: list[int]
    t_over_tstar: list[float]
    curves: list[list[float] | None]
    failed: dict[int, str]
    mean: list[float]
    std: list[float]
    mse: float
    mse_each: list[float]
    seconds: float
    dem_runs: int = 0  # DEM runs the route spent before the validation (calibration cost)
    calibration_seconds: float = 0.0  # wall time the route spent before the validation
    extra: dict = field(default_factory=dict)
    mse_se: float | None = None  # None: fewer than 3 packings ran

    @property
    def n_ran(self) -> int:
        return sum(curve is not None for curve in self.curves)

    def to_dict(self) -> dict:
        return asdict(self)


def model_runout(
    model: Model,
    column: MeasuredColumn,
    theta: Sequence[float],
    settings: SimulationSettings,
    seed: int,
    runout: RunoutMethod,
    dem_config: dict | None,
    progress: Callable[[float], None] | None = None,
) -> np.ndarray:
    """L* [K] at the measured t/t* of one DEM run of `model` at theta [p] on packing `seed`, with the
    engine of dem_config (the config's dem section), read as the column states its runout was read
    (else by `runout`, the config's). Raises one of FAILURES when the run fails.
    progress: callable(fraction of the run done) or None."""
    case = model.case(column, theta, settings, seed)
    trajectory = simulate_case(case, dem_config, progress=progress)
    t, curve = column.runout_reading(runout).curve(trajectory)
    return simulated_runout_at(t, curve, column)


def buildable_cases(
    model: Model,
    column: MeasuredColumn,
    points: Sequence[Sequence[float]],
    settings: SimulationSettings,
    seeds: Sequence[int],
) -> list[CollapseCase]:
    """The cases of `model` at each of points [n, p] on each packing seed, that can be built (a case
    that cannot fails again, and is reported, where its run is asked for): a batch for dem.run_ahead."""
    cases = []
    for theta in points:
        for seed in seeds:
            try:
                cases.append(model.case(column, theta, settings, seed))
            except FAILURES:
                pass
    return cases


def mse_jackknife(
    curves: Sequence[Sequence[float] | None],
    measured: ArrayLike,
    baseline: Sequence[Sequence[float] | None] | None = None,
) -> tuple[float, float | None]:
    """(runout MSE of the mean curve, its jackknife standard error over the packings) for curves
    [R][K] (L*; None where a run failed) against measured [K]; with `baseline` (another route's
    curves on the same R packings, the validation seeds), of the difference MSE - baseline's MSE,
    paired packing by packing (the shared packings' chaos cancels). Packings where either failed are
    left out; the error is None (JSON null) with fewer than 3 left, the value NaN with none."""
    keep = [k for k, c in enumerate(curves) if c is not None and (baseline is None or baseline[k] is not None)]
    measured = np.asarray(measured, float)

    def score(rows):
        value = runout_mse(np.mean([curves[k] for k in rows], axis=0), measured)
        if baseline is not None:
            value -= runout_mse(np.mean([baseline[k] for k in rows], axis=0), measured)
        return float(value)

    if not keep:
        return math.nan, None
    full = score(keep)
    n = len(keep)
    if n < 3:
        return full, None
    leave_one_out = np.array([score([k for k in keep if k != j]) for j in keep])
    return full, float(np.sqrt((n - 1) / n * np.sum((leave_one_out - leave_one_out.mean()) ** 2)))


def validate(
    route: str,
    model: Model,
    column: MeasuredColumn,
    theta: Sequence[float],
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_packings: int = 4,
    dem_runs: int = 0,
    calibration_seconds: float = 0.0,
    progress: Callable[[float], None] | None = None,
    first_packing: int = 0,
    seed0: int = VALIDATION_SEED0,
    made_ahead: bool = False,
) -> Validation:
    """The model at theta [p] run on n_packings packings, seeds seed0 + first_packing + k (by default
    the validation packings, which no calibration uses); dem_runs and calibration_seconds: what the
    route spent to find theta (reported beside the score). progress: callable(fraction of all the
    runs done) or None. made_ahead: the caller has made these runs ahead (dem.run_ahead) already."""
    started = time.perf_counter()
    seeds = [seed0 + first_packing + k for k in range(n_packings)]
    if not made_ahead:
        run_ahead(buildable_cases(model, column, [theta], settings, seeds), dem_config, route)
    curves, failed = [], {}
    for k, seed in enumerate(seeds):
        within = None if progress is None else (lambda f, k=k: progress((k + f) / n_packings))
        try:
            curves.append(model_runout(model, column, theta, settings, seed, runout, dem_config, within).tolist())
        except FAILURES as exc:  # reported with its packing, never averaged in
            log.warning("%s: validation run on packing %d failed: %s", route, seed, exc)
            curves.append(None)
            failed[seed] = failure_reason(exc)
    ran = np.array([c for c in curves if c is not None])
    mean = ran.mean(axis=0) if len(ran) else np.full(len(column.runout), math.nan)
    std = ran.std(axis=0, ddof=1) if len(ran) > 1 else np.full(len(column.runout), math.nan)
    return Validation(
        route=route,
        parameters=dict(zip(model.parameter_names, map(float, theta))),
        seeds=seeds,
        t_over_tstar=column.t_over_tstar.tolist(),
        curves=curves,
        failed=failed,
        mean=mean.tolist(),
        std=std.tolist(),
        mse=float(runout_mse(mean, column.runout)) if len(ran) else math.nan,
        mse_se=mse_jackknife(curves, column.runout)[1],
        mse_each=[float(runout_mse(np.array(c), column.runout)) if c is not None else math.nan for c in curves],
        seconds=time.perf_counter() - started,
        dem_runs=dem_runs,
        calibration_seconds=calibration_seconds,
    )


def bayesopt_model(
    model: Model,
    column: MeasuredColumn,
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    budget: int = 24,
    n_initial: int = 8,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
) -> OptimisationHistory:
    """GP expected-improvement BO of the runout MSE over `model`'s box, one DEM run per point on
    packing CALIBRATION_SEED + seed (seed also draws the initial design); a run that fails is
    recorded with its reason in the history's `failed` list (it counts against the budget, the GP
    never sees it)."""

    def dem_objective(theta: np.ndarray) -> float:
        try:
            curve = model_runout(model, column, theta, settings, CALIBRATION_SEED + seed, runout, dem_config)
        except FAILURES as exc:
            raise PointFailed(failure_reason(exc)) from exc
        return float(runout_mse(curve, column.runout))

    def reported(batch: int, seconds: float, values: np.ndarray) -> None:
        if progress is not None:
            progress(batch / budget)

    result = bayesian_optimisation(
        one_at_a_time(dem_objective),
        model.bounds.tolist(),
        list(model.parameter_names),
        BOSettings(budget=budget, n_initial=n_initial, seed=seed),
        progress=reported,
    )
    return result.history
