"""The inverse-design stage: what each job of workflow/rules/inverse.smk does.

Per measured column: a DEM run at the start point and one at the GNS optimum (run_dem_at), the
Bayesian optimisation directly on DEM runs (run_bayesopt), the comparison of the calibration
routes (run_comparison); the jobs that run a GNS (the inverse design, the parameter recovery) are
pipeline/inverse_design.py's, apart so that these load no torch. The methods live in
calibration.compare; here they meet the pipeline's files: inputs read, outputs written atomically,
progress logged. Times of the routes come from the Snakemake benchmark files (pipeline.benchmarks).
Its report section: pipeline/inverse_section.py.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path

from calibration.compare import (
    BO_MAX_RUNS,
    Route,
    bayesopt_on_dem,
    comparison_routes,
    dem_run,
    markdown_table,
    measured_case_fields,
    plot_bayesopt,
    plot_comparison,
    validation_summary,
    write_bayesopt,
    write_table,
)
from calibration.inverse_result import read_result
from calibration.measured import load_column
from calibration.measured_column import MeasuredColumn
from calibration.objective import objective
from dem.atomic import StrPath
from dem.progress import progress_logger
from dem.run_store import keeps_runs
from dem.runout import RunoutMethod, check_same_method, runout_curve
from dem.trajectory import read_trajectory, write_trajectory
from gns.dataset import read_metadata
from pipeline.benchmarks import benchmark_seconds

log = logging.getLogger(__name__)
START_NAMES = ("friction", "restitution")  # the order of the config's inverse.start


# -- DEM runs of a measured column: at a point, and Bayesian optimisation -------------------------------
def run_dem_point(
    measured_path: StrPath,
    metadata_path: StrPath,
    params: dict,
    out_path: StrPath,
    *,
    runout: dict | None,
    seed: int = 0,
    name: str = "",
    dem: dict | None = None,
) -> dict:
    """DEM run of a measured column at params with the GNS dataset's DEM model and the engine of
    `dem` (the config's dem section); writes the trajectory (atomically) and returns its validation
    summary (L* read by `runout`, the config's runout section)."""
    measured = load_column(measured_path)
    fields = measured_case_fields(read_metadata(metadata_path), seed)
    trajectory = dem_run(
        measured, params, fields, name=name, progress=progress_logger(f"DEM run {name}", log), dem_config=dem
    )
    write_trajectory(out_path, trajectory)
    summary = validation_summary(trajectory, measured, measured.runout_reading(runout))
    log.info("%s: objective %.4g against %s", name, summary["mse"], measured.name)
    return summary


def run_dem_at(
    measured_path: StrPath,
    metadata_path: StrPath,
    out_path: StrPath,
    *,
    runout: dict | None,
    seed: int = 0,
    dem: dict | None = None,
    result_path: StrPath | None = None,
    start: Sequence[float] | None = None,
) -> tuple[str, dict, dict]:
    """The DEM run of rule inverse_validate (at the GNS optimum of the inverse.json at
    `result_path`) or, without one, of rule inverse_start (at `start`, the config's inverse.start
    (mu, e)): run_dem_point named "gns_optimum" or "start". Returns (name, params, its summary)."""
    if result_path:
        result = read_result(result_path)
        params, name = dict(zip(result["names"], result["best_params"])), "gns_optimum"
    elif start is not None:
        params, name = dict(zip(START_NAMES, start)), "start"
    else:
        raise ValueError(f"DEM run to {out_path}: give the inverse design's result or the start point")
    summary = run_dem_point(
        measured_path, metadata_path, params, out_path, runout=runout, seed=seed, name=name, dem=dem
    )
    return name, params, summary


@keeps_runs("out_json")
def run_bayesopt(
    measured_path: StrPath,
    metadata_path: StrPath,
    out_json: StrPath,
    out_figure: StrPath,
    out_best: StrPath,
    bounds: Sequence[Sequence[float]],
    *,
    runout: dict | None,
    budget: int = BO_MAX_RUNS,
    n_initial: int = 6,
    seed: int = 0,
    dem: dict | None = None,
) -> dict:
    """The BO arm: bayesopt.json (every run), its figure and the best run's trajectory; every
    objective reads L* by `runout` (the config's runout section), every run uses the engine of
    `dem` (the config's dem section)."""
    measured = load_column(measured_path)
    fields = measured_case_fields(read_metadata(metadata_path), seed)
    runout = measured.runout_reading(runout)  # the column's stated method, else the config's
    progress = progress_logger(f"BO on DEM runs of {measured.name}", log)
    history, best, seconds = bayesopt_on_dem(
        measured, fields, bounds, runout, budget, n_initial, seed, dem_config=dem, progress=progress
    )
    write_trajectory(out_best, best)
    write_bayesopt(history, seconds, out_json, runout)
    data = json.loads(Path(out_json).read_text())
    plot_bayesopt(data, out_figure, title=f"BO on DEM runs of {measured.name}")
    return data


# -- GNS inverse design and parameter recovery ----------------------------------------------------------
# -- the comparison of the calibration routes ---------------------------------------------------------
def plot_validation_runout(
    measured: MeasuredColumn, trajectories: dict, path: StrPath, runout: RunoutMethod, title: str = ""
) -> None:
    """DEM runout curves at each route's optimum against the measured points (the paper's Fig. 10).

    trajectories: {label: Trajectory}; labels get their objective appended.
    """
    from doe.plots import plot_runout_comparison

    curves = {
        f"{label}, MSE {objective(t, measured, runout):.3f}": runout_curve(t, runout)
        for label, t in trajectories.items()
    }
    plot_runout_comparison(measured, curves, path, title=title)


def run_comparison(
    measured_path: StrPath,
    inverse_path: StrPath,
    validation_path: StrPath,
    start_path: StrPath,
    out_table: StrPath,
    out_figure: StrPath,
    out_runout: StrPath,
    benchmarks: dict,
    dem_runs: dict,
    *,
    runout: dict | None,
    bayesopt_path: StrPath | None = None,
    bayesopt_best_path: StrPath | None = None,
    doe_validation: dict | None = None,
) -> list[Route]:
    """The comparison of one measured column: table (CSV), accuracy-cost figure, runout figure.

    benchmarks: {"start" | "gns_dataset" | "gns_training" | "gns_validation" | "doe" | "bayesopt":
    [benchmark files], "doe_validation": {model: [files]}}; dem_runs: {"gns_dataset": n, "doe": n}.
    doe_validation: {model: trajectory path} of the DoE's validation runs (None: no DoE arm).
    runout: the config's runout section (the column's stated method replaces its own); every
    validated L* is read by it, and the inverse design's and the BO's results must have been scored
    by it too (else RunoutError).
    """
    measured = load_column(measured_path)
    inverse = read_result(inverse_path)
    runout = measured.runout_reading(runout)
    check_same_method(inverse.get("runout"), runout, f"inverse design {inverse_path}")
    seconds = lambda key: benchmark_seconds(benchmarks.get(key, []))[0]  # noqa: E731
    times = {
        "start": seconds("start"),
        "gns_dataset": (seconds("gns_dataset"), dem_runs["gns_dataset"]),
        "gns_training": seconds("gns_training"),
        "gns_validation": seconds("gns_validation"),
        "doe": (seconds("doe"), dem_runs.get("doe", 0)),
        "bayesopt": seconds("bayesopt"),
        "doe_validation": {m: benchmark_seconds(p)[0] for m, p in benchmarks.get("doe_validation", {}).items()},
    }
    doe = {model: read_trajectory(path) for model, path in (doe_validation or {}).items()}
    bayesopt = json.loads(Path(bayesopt_path).read_text()) if bayesopt_path else None
    if bayesopt is not None:
        check_same_method(bayesopt.get("runout"), runout, f"Bayesian optimisation {bayesopt_path}")
    validation, start = read_trajectory(validation_path), read_trajectory(start_path)
    routes = comparison_routes(measured, inverse, validation, start, times, runout, doe, bayesopt)
    write_table(routes, out_table)
    plot_comparison(routes, out_figure, title=f"calibration routes for {measured.name}")
    curves = {
        f"start ({start.attrs['friction']:.2f}, {start.attrs['restitution']:.2f})": start,
        f"GNS optimum ({validation.attrs['friction']:.2f}, {validation.attrs['restitution']:.2f})": validation,
    }
    curves.update(
        {f"DoE {m} optimum ({t.attrs['friction']:.2f}, {t.attrs['restitution']:.2f})": t for m, t in doe.items()}
    )
    if bayesopt_best_path:
        best = read_trajectory(bayesopt_best_path)
        curves[f"BO best run ({best.attrs['friction']:.2f}, {best.attrs['restitution']:.2f})"] = best
    plot_validation_runout(measured, curves, out_runout, runout, title=f"{measured.name}: DEM runs at each optimum")
    log.info("comparison:\n%s", markdown_table(routes))
    return routes
