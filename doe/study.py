"""The DoE calibration study of one measured column: design rows for the DEM stage, responses from
the DEM runs, the analysis, and the validation case at each model's optimum.

The stage layer (pipeline/doe.py) calls these for the Snakemake jobs and writes the report section.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import pandas as pd

from calibration.objective import check_same_column, runout_mse
from dem.atomic import atomic_path
from dem.runout import RunoutMethod, check_same_method, runout_at
from dem.trajectory import read_trajectory
from doe.design import design_cases
from doe.regression import analyse, prediction_expression

if TYPE_CHECKING:
    from calibration.measured import MeasuredColumn
    from dem.case import CollapseCase
    from doe.design import Factor

RUNOUT_PREFIX = "L_star_t"  # response columns L_star_t0.5, ... : simulated L* at the measured t/t*
RUNOUT_METHOD_COLUMN = "runout_method"  # the runout method (JSON) every response was read by


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
            "material": case.material.name,
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
    simulated L* at each measured t/t* (columns L_star_t<t>), plus dem_wall_time_s and the runout
    method they were read by (column runout_method, JSON).

    trajectory_paths: {run_id: path of the run's trajectory HDF5}; runout: how L* is read.
    """
    runout = RunoutMethod.from_config(runout)
    missing = [r for r in design["run_id"] if r not in trajectory_paths]
    if missing:
        raise KeyError(f"no trajectory for design run(s) {missing}")
    records = []
    for run_id in design["run_id"]:
        trajectory = read_trajectory(trajectory_paths[run_id])
        check_same_column(trajectory.attrs, measured, str(trajectory_paths[run_id]))
        values = runout_at(trajectory, measured.t_over_tstar, runout)
        record = {
            "run_id": run_id,
            "mse": runout_mse(values, measured.runout),
            "dem_wall_time_s": float(trajectory.attrs.get("wall_time_s", math.nan)),
            RUNOUT_METHOD_COLUMN: json.dumps(runout.to_config(), sort_keys=True),
        }
        record.update({f"{RUNOUT_PREFIX}{t:g}": float(v) for t, v in zip(measured.t_over_tstar, values)})
        records.append(record)
    return design.merge(pd.DataFrame(records), on="run_id")


def run_analysis(responses: pd.DataFrame, factors: Sequence[Factor], models: Iterable[str]) -> tuple[dict, dict]:
    """analyse() with the prediction expressions and the analysis time added to the summary."""
    start = time.perf_counter()
    fits, summary = analyse(responses, factors, "mse", models)
    for model, fit in fits.items():
        summary["models"][model]["expression"] = prediction_expression(fit)
    summary["analysis_time_s"] = time.perf_counter() - start
    return fits, summary


def validation_case(summary: dict, model: str, measured: MeasuredColumn, **case_fields: Any) -> CollapseCase:
    """The DEM case at `model`'s optimum (analysis summary from run_analysis) on the measured column."""
    if model not in summary["models"]:
        raise KeyError(f"model {model!r} not in the analysis; fitted: {list(summary['models'])}")
    optimum = summary["models"][model]["optimum"]["natural"]
    return measured.collapse_case(**optimum, name=f"doe_validation_{model}", **case_fields)


def read_responses(path: str | os.PathLike, runout: RunoutMethod) -> pd.DataFrame:
    """responses.csv of collect_responses; RunoutError when it was read by another runout method."""
    table = pd.read_csv(path)
    runout = RunoutMethod.from_config(runout)
    methods = set(table[RUNOUT_METHOD_COLUMN].fillna("")) if RUNOUT_METHOD_COLUMN in table else {""}
    for found in methods:
        check_same_method(json.loads(found) if found else None, runout, f"DoE responses {path}")
    return table


def write_responses(path: str | os.PathLike, responses: pd.DataFrame) -> None:
    with atomic_path(path) as tmp:
        responses.to_csv(tmp, index=False)
