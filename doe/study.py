"""The DoE calibration study of one measured column: design rows for the DEM stage, responses from
the DEM runs, the analysis, and the validation case at each model's optimum.

The stage layer (pipeline/doe.py) calls these for the Snakemake jobs; pipeline/doe_section.py writes the
report section.

A run that failed (dem.engines.FAILURES: here a trajectory that cannot be read, or holds no runout
front) is kept in the responses with its reason (column `failure`, mse NaN) and left out of the
fit (`fitted_runs`); the analysis summary lists it. A responses file with a run that has no
response and no failure recorded is refused (`read_responses`), naming the file, line and run.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from calibration.objective import check_same_column, runout_mse
from dem.atomic import atomic_path
from dem.engines import FAILURES, failure_reason
from dem.runout import RunoutMethod, check_same_method, runout_at
from dem.trajectory import read_trajectory
from doe.design import design_cases
from doe.regression import RegressionError, analyse, prediction_expression

if TYPE_CHECKING:
    from calibration.measured_column import MeasuredColumn
    from dem.case import CollapseCase
    from doe.design import Factor

log = logging.getLogger(__name__)

RUNOUT_PREFIX = "L_star_t"  # response columns L_star_t0.5, ... : simulated L* at the measured t/t*
RUNOUT_METHOD_COLUMN = "runout_method"  # the runout method (JSON) every response was read by
FAILURE_COLUMN = "failure"  # "ExceptionName: message" of a run that failed, "" where it ran


class ResponsesError(ValueError):
    """A design run has no response; the message names the file (or table), the line and the run."""


def fitted_runs(responses: pd.DataFrame) -> pd.DataFrame:
    """The runs of a responses table that ran (finite mse): those the surface is fitted to."""
    return responses[np.isfinite(responses["mse"].to_numpy(float))]


def failure_reasons(responses: pd.DataFrame) -> list[str]:
    """[n] the reason each run failed, "" where it ran (and for every run of a table without the
    column; a CSV reads an empty reason back as NaN)."""
    if FAILURE_COLUMN not in responses:
        return [""] * len(responses)
    return ["" if pd.isna(why) else str(why) for why in responses[FAILURE_COLUMN]]


def failures(responses: pd.DataFrame) -> tuple[dict[str, str], str]:
    """({run_id: reason} of the runs that failed, the same in a sentence for the summary)."""
    failed = {str(run_id): why for run_id, why in zip(responses["run_id"], failure_reasons(responses)) if why}
    sentence = (
        f"{len(failed)} of {len(responses)} DEM runs failed and are left out of the fit: "
        + "; ".join(f"{run_id}: {why}" for run_id, why in failed.items())
        if failed
        else "every DEM run ran"
    )
    return failed, sentence


def case_rows(design: pd.DataFrame, measured: MeasuredColumn, dataset: str, **case_fields: Any) -> list[dict]:
    """Case-table rows (dem.grid format) of every design run, for the DEM stage's rules.

    dataset: the case-table dataset name of this study (e.g. "doe_quartz"); case_id = run_id.
    case_fields: CollapseCase fields shared by every run (size_scale, duration_over_tstar, ...).
    Each row is checked by building its CollapseCase.
    """
    rows = []
    for run_id, case in design_cases(design, measured, **case_fields).items():
        row = {
            "dataset": dataset,
            "case_id": run_id,
            "split": "doe",
            "material": case.material.to_config(),
            "L_i": case.L_i,
            "aspect_ratio": case.aspect_ratio,
            "friction": case.friction,
            "restitution": case.restitution,
            "seed": case.seed,
            "output_interval": case.output_interval,
        }
        row.update(case_fields)
        rows.append(row)
    return rows


def collect_responses(
    design: pd.DataFrame, trajectory_paths: dict, measured: MeasuredColumn, runout: RunoutMethod
) -> pd.DataFrame:
    """The design table with the response of every run: mse (calibration.objective) and the
    simulated L* at each measured t/t* (columns L_star_t<t>), plus dem_wall_time_s, the runout
    method they were read by (column runout_method, JSON) and failure (the reason a run failed, its
    responses NaN; "" where it ran).

    trajectory_paths: {run_id: path of the run's trajectory HDF5}; runout: how L* is read. A design
    run with no path is a ResponsesError naming it.
    """
    runout = RunoutMethod.from_config(runout)
    missing = [r for r in design["run_id"] if r not in trajectory_paths]
    if missing:
        raise ResponsesError(
            f"no trajectory file for design run(s) {missing} among the {len(trajectory_paths)} given "
            f"(each named <run_id>.h5)"
        )
    records = []
    for run_id in design["run_id"]:
        path = str(trajectory_paths[run_id])
        try:
            trajectory = read_trajectory(path)
            check_same_column(trajectory.attrs, measured, path)
            values = runout_at(trajectory, measured.t_over_tstar, runout)
            failure, seconds = "", float(trajectory.attrs.get("wall_time_s", math.nan))
        except FAILURES as exc:  # recorded with its reason, left out of the fit
            values, failure, seconds = np.full(len(measured.t_over_tstar), math.nan), failure_reason(exc), math.nan
            log.warning("DoE run %s failed, left out of the fit: %s", run_id, failure)
        record = {
            "run_id": run_id,
            "mse": runout_mse(values, measured.runout),
            "dem_wall_time_s": seconds,
            RUNOUT_METHOD_COLUMN: json.dumps(runout.to_config(), sort_keys=True),
            FAILURE_COLUMN: failure,
        }
        record.update({f"{RUNOUT_PREFIX}{t:g}": float(v) for t, v in zip(measured.t_over_tstar, values)})
        records.append(record)
    return design.merge(pd.DataFrame(records), on="run_id")


def run_analysis(responses: pd.DataFrame, factors: Sequence[Factor], models: Iterable[str]) -> tuple[dict, dict]:
    """analyse() of the runs that ran (`fitted_runs`) with the prediction expressions and the
    analysis time added to the summary, n_runs (the runs made), n_fitted, failed {run_id: reason}
    and failures (a sentence)."""
    start = time.perf_counter()
    failed, sentence = failures(responses)
    try:
        fits, summary = analyse(fitted_runs(responses), factors, "mse", models)
    except RegressionError as exc:
        raise RegressionError(f"{exc} ({sentence})") from exc
    for model, fit in fits.items():
        summary["models"][model]["expression"] = prediction_expression(fit)
    summary.update(n_runs=int(len(responses)), n_fitted=int(len(responses) - len(failed)), failed=failed)
    summary.update(failures=sentence, analysis_time_s=time.perf_counter() - start)
    return fits, summary


def validation_case(summary: dict, model: str, measured: MeasuredColumn, **case_fields: Any) -> CollapseCase:
    """The DEM case at `model`'s optimum (analysis summary from run_analysis) on the measured column."""
    if model not in summary["models"]:
        raise KeyError(f"model {model!r} not in the analysis; fitted: {list(summary['models'])}")
    optimum = summary["models"][model]["optimum"]["natural"]
    return measured.collapse_case(**optimum, name=f"doe_validation_{model}", **case_fields)


def read_responses(path: str | os.PathLike, runout: RunoutMethod) -> pd.DataFrame:
    """responses.csv of collect_responses; RunoutError when it was read by another runout method,
    ResponsesError (naming the line and the run) when a run has no response and no failure
    recorded. A failed run (its reason in column failure) is kept; `fitted_runs` leaves it out."""
    table = pd.read_csv(path)
    runout = RunoutMethod.from_config(runout)
    methods = set(table[RUNOUT_METHOD_COLUMN].fillna("")) if RUNOUT_METHOD_COLUMN in table else {""}
    for found in methods:
        check_same_method(json.loads(found) if found else None, runout, f"DoE responses {path}")
    if FAILURE_COLUMN in table:
        table[FAILURE_COLUMN] = failure_reasons(table)
    check_responses(table, f"DoE responses {path}")
    return table


def check_responses(table: pd.DataFrame, where: str) -> None:
    """ResponsesError naming `where`, the line (of its CSV: the header is line 1) and the run of every
    run without a response (mse or an L_star_t column empty) and without a failure recorded."""
    for column in ("run_id", "mse"):
        if column not in table:
            raise ResponsesError(f"{where}: no column {column!r}")
    columns = ["mse"] + [c for c in table.columns if c.startswith(RUNOUT_PREFIX)]
    values = table[columns].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    failed = np.array([why != "" for why in failure_reasons(table)], bool)
    missing = ~np.isfinite(values) & ~failed[:, None]
    rows = np.flatnonzero(missing.any(axis=1))
    if len(rows):
        runs = [
            f"line {k + 2}, run {table['run_id'].iloc[k]} ({', '.join(np.array(columns)[missing[k]])} empty)"
            for k in rows
        ]
        raise ResponsesError(
            f"{where}: {len(rows)} design run(s) without a response and without a failure recorded: "
            + "; ".join(runs)
            + " (rerun the DoE analysis)"
        )


def write_responses(path: str | os.PathLike, responses: pd.DataFrame) -> None:
    with atomic_path(path) as tmp:
        responses.to_csv(tmp, index=False)
