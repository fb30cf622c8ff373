"""The DoE route for the calibrated model (calibration/calibrated.py): a face-centred central
composite design over the model's parameter box (mu, e and the mechanism parameter, when it has
one), one DEM run of the measured column per design point, and the quadratic response surface of
the runout MSE with its ANOVA, lack-of-fit test and bounded optimum. Optionally the 3-level full
factorial too, from the same runs plus the grid points the CCD lacks (k = 3: 30 runs, the GNS
route's cost): the DoE at the GNS's price, each design's surface fitted to its own runs.

Packings: every non-replicate run starts from one packing (CALIBRATION_SEED + seed, the packing the
other calibration routes run on), so differences between design points are due to the parameters
alone (common random numbers); the centre replicates use other packings and measure the pure error.

A run that fails (dem.engines.FAILURES) is kept in the responses table with its reason
and left out of the fit; the summary lists it.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from calibration.calibrated import CALIBRATION_SEED, model_runout
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.objective import runout_mse
from dem.engines import FAILURES, failure_reason
from dem.runout import RunoutMethod
from doe.design import Factor, face_centred_ccd, three_level_factorial
from doe.regression import RegressionError, SurfaceFit, analyse, prediction_expression
from doe.study import FAILURE_COLUMN, RUNOUT_METHOD_COLUMN, RUNOUT_PREFIX, failures, fitted_runs

log = logging.getLogger(__name__)

CCD = "face-centred CCD"
FULL_FACTORIAL = "3-level full factorial"  # the CCD's runs and the rest of the 3^k grid
SURFACE = "quadratic"


def model_factors(model: Model) -> tuple[Factor, ...]:
    """One design factor per parameter of `model`, over its bounds (natural units)."""
    return tuple(
        Factor(name, float(low), float(high)) for name, (low, high) in zip(model.parameter_names, model.bounds)
    )


def model_doe(
    model: Model,
    column: MeasuredColumn,
    settings: SimulationSettings,
    runout: RunoutMethod | dict | None,
    dem_config: dict | None,
    centre_replicates: int = 3,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
    full_factorial: bool = False,
) -> tuple[pd.DataFrame, dict[str, tuple[dict, SurfaceFit]]]:
    """DoE calibration of `model` on one measured column: (responses, {design: (summary, its fitted
    quadratic surface)}) for the face-centred CCD (CCD) and, with full_factorial, the 3-level full
    factorial (FULL_FACTORIAL): one DEM campaign (doe.design.three_level_factorial, whose first runs
    are the CCD's), each design's surface fitted to its own runs.

    responses: the design table (doe.design columns; seed = the packing seed of the run; ccd = the
    run belongs to the CCD) with mse (runout MSE against column.runout, NaN where the run failed),
    L_star_t<t> (simulated L* at the measured t/t*), dem_wall_time_s, runout_method (JSON: `runout`
    with the column's stated method in place of its own, MeasuredColumn.runout_reading) and failure
    (reason, "" where it ran). summary (JSON-ready), per design: design, model, n_runs (its DEM
    runs), n_fitted, failed {run_id: reason}, failures (a sentence), centre_replicates,
    packing_seeds, dem_seconds (its runs' wall time), and doe.regression.analyse's summary of the
    quadratic surface (pure_error, best_run, models.quadratic: coefficients, effects (type-III
    ANOVA), lack_of_fit, optimum in coded and natural units, expression), analysis_time_s.
    progress: callable(fraction of the runs done) or None.
    """
    runout = column.runout_reading(runout)  # the column's stated method, else the config's
    factors = model_factors(model)
    if full_factorial:
        design = three_level_factorial(factors, centre_replicates, CALIBRATION_SEED + seed)
    else:
        design = face_centred_ccd(factors, centre_replicates, CALIBRATION_SEED + seed).assign(ccd=True)
    method = json.dumps(runout.to_config(), sort_keys=True)
    records = []
    for done, row in enumerate(design.itertuples(index=False), start=1):
        theta = [float(getattr(row, f.name)) for f in factors]
        started = time.perf_counter()
        try:
            curve = model_runout(model, column, theta, settings, int(row.seed), runout, dem_config)
            failure = ""
        except FAILURES as exc:  # recorded with its reason, left out of the fit
            curve = np.full(len(column.runout), math.nan)
            failure = failure_reason(exc)
            log.warning("DoE run %s at %s failed: %s", row.run_id, np.round(theta, 4).tolist(), failure)
        record = {
            "run_id": row.run_id,
            "mse": float(runout_mse(curve, column.runout)),
            "dem_wall_time_s": time.perf_counter() - started,
            RUNOUT_METHOD_COLUMN: method,
            FAILURE_COLUMN: failure,
        }
        record.update({f"{RUNOUT_PREFIX}{t:g}": float(v) for t, v in zip(column.t_over_tstar, curve)})
        records.append(record)
        if progress is not None:
            progress(done / len(design))
    responses = design.merge(pd.DataFrame(records), on="run_id")
    designs = (CCD, FULL_FACTORIAL) if full_factorial else (CCD,)
    return responses, {
        label: design_surface(design_runs(responses, label), factors, model, label, column.name, centre_replicates)
        for label in designs
    }


def design_runs(responses: pd.DataFrame, design: str) -> pd.DataFrame:
    """The rows of model_doe's responses that belong to `design` (CCD: those marked ccd; FULL_FACTORIAL: all)."""
    return responses if design == FULL_FACTORIAL else responses[responses["ccd"]]


def design_surface(
    responses: pd.DataFrame,
    factors: tuple[Factor, ...],
    model: Model,
    design: str,
    column_name: str,
    centre_replicates: int,
) -> tuple[dict, SurfaceFit]:
    """(summary, fitted quadratic surface) of one design's runs (model_doe's responses rows)."""
    failed, sentence = failures(responses)
    started = time.perf_counter()
    try:
        fits, analysis = analyse(fitted_runs(responses), factors, "mse", models=(SURFACE,))
    except RegressionError as exc:
        raise RegressionError(f"{model.name} DoE ({design}) on {column_name}: {exc} ({sentence})") from exc
    analysis["models"][SURFACE]["expression"] = prediction_expression(fits[SURFACE])
    analysis.pop("n_runs")  # the runs fitted: n_fitted below, beside the runs made
    summary = {
        "design": design,
        "model": model.name,
        "n_runs": int(len(responses)),
        "n_fitted": int(len(responses) - len(failed)),
        "failed": failed,
        "failures": sentence,
        "centre_replicates": centre_replicates,
        "packing_seeds": sorted({int(s) for s in responses["seed"]}),
        "dem_seconds": float(responses["dem_wall_time_s"].sum()),
        **analysis,
        "analysis_time_s": time.perf_counter() - started,
    }
    return summary, fits[SURFACE]
