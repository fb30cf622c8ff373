"""The DoE stage (workflow/rules/doe.smk): what each of its Snakemake jobs does. For every measured
column: the design table, the responses of the DEM runs and the analysis (regression, ANOVA, optimum,
response-surface figure), and a DEM validation run at each model's optimum.

The methods live in doe/ (design, regression, plots, doe.study); this module reads and writes the
stage's files. One entry function per workflow script: design, analyse, validate. Its report
section: pipeline/doe_section.py.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from calibration.measured import load_column
from calibration.objective import objective
from dem.atomic import StrPath, write_json
from dem.engines import simulate_case
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from dem.trajectory import write_trajectory
from doe.design import design_cases, design_from_config, factors_from_config, read_design, write_design
from doe.plots import plot_response_surfaces
from doe.study import collect_responses, run_analysis, validation_case, write_responses

log = logging.getLogger(__name__)


# ---- entry functions, one per workflow script ----


def design(measured_path: StrPath, doe: dict, out_path: StrPath) -> pd.DataFrame:
    """Write the DoE design table (doe config section `doe`) of one measured column at `out_path`,
    after checking every run builds a case on the column's geometry. Returns the table."""
    table = design_from_config(doe)
    measured = load_column(measured_path)
    cases = design_cases(table, measured, size_scale=doe["size_scale"], duration_over_tstar=doe["duration_over_tstar"])
    write_design(out_path, table)
    log.info(
        "%d runs on %s (a = %g, L_i = %g m), %d grains each",
        len(table),
        measured.name,
        measured.aspect_ratio,
        measured.L_i,
        next(iter(cases.values())).n_particles,
    )
    return table


def analyse(
    design_path: StrPath,
    measured_path: StrPath,
    trajectory_paths: Iterable,
    doe: dict,
    runout: RunoutMethod | dict | str | None,
    responses_path: StrPath,
    analysis_path: StrPath,
    surface_path: StrPath,
) -> dict:
    """Responses of the DoE runs (runout MSE against the measured curve) -> `responses_path` (CSV),
    regression/ANOVA and optimum -> `analysis_path` (JSON, with the runout method recorded under
    "runout"), response-surface figure -> `surface_path`. Returns the analysis summary.

    trajectory_paths: the runs' trajectory HDF5 files, each named <run_id>.h5; runout: the config's
    runout method.
    """
    table = read_design(design_path)
    measured = load_column(measured_path)
    paths = {Path(p).stem: p for p in trajectory_paths}
    runout = measured.runout_reading(runout)  # the column's stated method, else the config's
    responses = collect_responses(table, paths, measured, runout)
    write_responses(responses_path, responses)
    fits, summary = run_analysis(responses, factors_from_config(doe), doe["models"])
    summary["runout"] = runout.to_config()
    write_json(analysis_path, summary)
    plot_response_surfaces(fits, responses, surface_path, measured_name=measured.name)
    for model, fit in summary["models"].items():
        log.info(
            "%s: R2 %.3f, optimum %s, predicted MSE %.3f",
            model,
            fit["r_squared"],
            fit["optimum"]["natural"],
            fit["optimum"]["predicted"],
        )
    return summary


def validate(
    analysis_path: StrPath,
    measured_path: StrPath,
    model: str,
    case_fields: dict,
    dem: dict | None,
    runout: RunoutMethod | dict | str | None,
    out_path: StrPath,
) -> float:
    """DEM validation run at `model`'s DoE optimum (analysis.json at `analysis_path`) on the measured
    column, through the configured engine (`dem`: the config's dem section), written atomically at
    `out_path` (trajectory HDF5). Returns its MSE against the measured runout.

    case_fields: CollapseCase fields of the run (size_scale, duration_over_tstar, seed).
    """
    summary = json.loads(Path(analysis_path).read_text())
    measured = load_column(measured_path)
    case = validation_case(summary, model, measured, **case_fields)
    log.info("validation %s: mu %.4f, e %.4f, %d grains", case.name, case.friction, case.restitution, case.n_particles)
    trajectory = simulate_case(case, dem, progress=progress_logger(f"collapse {case.name}", log))
    write_trajectory(out_path, trajectory)
    mse = objective(trajectory, measured, measured.runout_reading(runout))
    log.info("MSE against %s: %.4f", measured.name, mse)
    return mse
