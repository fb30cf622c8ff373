"""The inverse-design stage: what each job of workflow/rules/inverse.smk does, and the stage's
report section (results/report/inverse.md).

Per measured column: a DEM run at the start point and one at the GNS optimum (run_dem_at), the
Bayesian optimisation directly on DEM runs (run_bayesopt), the comparison of the calibration
routes (run_comparison), then the section (write_section); the jobs that run a GNS (the inverse
design, the parameter recovery) are pipeline/inverse_design.py's, apart so that these load no
torch. The methods live in calibration.compare; here they meet the pipeline's files: inputs read,
outputs written atomically, progress logged. Times of the routes come from the Snakemake benchmark files
(pipeline.benchmarks).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

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
    read_table,
    validation_summary,
    write_bayesopt,
    write_table,
)
from calibration.inverse_result import read_result
from calibration.measured import load_column
from calibration.measured_column import MeasuredColumn
from calibration.objective import objective
from dem.atomic import StrPath, write_text
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


# -- the report section --------------------------------------------------------------------------------
def section(
    name: str,
    measured: MeasuredColumn,
    routes: list[Route],
    inverse: dict,
    figures: dict,
    section_path: StrPath,
    recovery: dict | None = None,
) -> str:
    """Markdown report section of one measured column (links relative to section_path)."""
    here = Path(section_path).parent
    rel = {k: Path(os.path.relpath(v, here)).as_posix() for k, v in figures.items()}
    post = inverse["posterior"]
    lines = [f"### {name}: {measured.material}, a = {measured.aspect_ratio:g}, L_i = {measured.L_i:g} m", ""]
    geometry = inverse["geometry"]
    if geometry["distance"] > 0.05:
        lines += [
            f"**Warning:** the GNS was not trained on this column: the nearest training column "
            f"(a = {geometry['nearest'][0]:g}, L_i = {geometry['nearest'][1]:g} m) is "
            f"{geometry['distance']:.0%} away.",
            "",
        ]
    lines += [
        f"GNS inverse design: {len(inverse['starts'])} L-BFGS-B starts in lockstep ({inverse['gradient']} "
        f"gradients through the checkpointed rollout), {inverse['n_batches']} batched rollouts, "
        f"online time {inverse['seconds']['online']:.1f} s. Optimum (GNS objective "
        f"{inverse['best_value']:.3f}):",
        "",
        "| parameter | optimum | std | 95% interval | identifiable |",
        "|---|---|---|---|---|",
    ]
    for p in post["parameters"]:
        lines.append(
            f"| {p['name']} | {p['value']:.3f} | {p['std']:.3f} | [{p['low']:.3f}, {p['high']:.3f}] | "
            f"{'yes' if p['identifiable'] else 'no: ' + p['why']} |"
        )
    lines += [
        "",
        f"Posterior correlation of the two parameters: {post['correlation'][0][1]:.2f}; noise: "
        f"{post['sigma_source']} (std {np.mean(post['sigma']):.3g} in L*).",
        "",
        "| start (mu, e) | end (mu, e) | GNS objective | iterations | rollouts | L-BFGS-B |",
        "|---|---|---|---|---|---|",
    ]
    for s in inverse["starts"]:
        lines.append(
            f"| {s['start'][0]:.3f}, {s['start'][1]:.3f} | {s['params'][0]:.3f}, {s['params'][1]:.3f} | "
            f"{s['iterates'][0]['value']:.4g} -> {s['value']:.4g} | {s['n_iterations']} | "
            f"{s['n_evaluations']} | {s['message']} |"
        )
    rough = inverse.get("roughness")
    if rough:
        listed = lambda values: ", ".join("failed" if v is None else f"{v:.3g}" for v in values)  # noqa: E731
        lines += [
            "",
            f"Roughness of the GNS objective: within {rough['radius']:g} of the optimum it spans "
            f"{rough['spread']:.3g} ({listed(rough['values'])} around "
            f"{rough['optimum_value']:.3g}); the posterior's steps of {rough['jacobian_step']:g} give "
            f"{listed(rough['jacobian_step_values'])}. Where the spread is comparable, "
            "the rollout is chaotic in (mu, e) at that scale (as the DEM is between packings): local "
            "gradients, exact or finite-difference, describe that noise rather than the trend.",
        ]
    lines += [
        "",
        "Validated against the measured runout (DEM runs at each optimum; the paper: start 0.66, "
        "GNS 0.10, DoE 0.17 for quartz):",
        "",
        markdown_table(routes),
        "",
    ]
    for key, caption in (
        ("paths", "optimisation paths over the objective landscape (Fig. 2)"),
        ("deposits", "GNS deposits during the optimisation (Fig. 9)"),
        ("runout", "DEM runout at each optimum against the measurement (Fig. 10)"),
        ("comparison", "validated objective against DEM runs and wall time (Table 5)"),
        ("bayesopt", "Bayesian optimisation on DEM runs"),
    ):
        if key in rel:
            lines += [f"![{caption}]({rel[key]})", ""]
    return "\n".join(lines)


def report_section(
    names: Sequence[str],
    measured_paths: Sequence[StrPath],
    inverse_paths: Sequence[StrPath],
    table_paths: Sequence[StrPath],
    figures: dict,
    section_path: StrPath,
    recovery_paths: Sequence[StrPath] = (),
    recovery_figures: Sequence[StrPath] = (),
) -> str:
    """The inverse-design report section: per measured column the optimum with its uncertainty, the
    comparison table and figures; then the parameter recovery of each GNS on synthetic targets.

    figures: {name: {"paths", "deposits", "runout", "comparison", "bayesopt": path}}.
    """
    parts = [
        "Calibration of (mu, e) through the trained GNS (L-BFGS-B within bounds, as Jiang et al. 2024), "
        "checked by DEM runs at the optimum and compared with the DoE and with Bayesian optimisation "
        "directly on DEM runs. Wall times are sums of job times (one core each) from the benchmark files.",
        "",
    ]
    for k, name in enumerate(names):
        parts.append(
            section(
                name,
                load_column(measured_paths[k]),
                read_table(table_paths[k]),
                read_result(inverse_paths[k]),
                figures[name],
                section_path,
            )
        )
    here = Path(section_path).parent
    for path, figure in zip(recovery_paths, recovery_figures):
        summary = json.loads(Path(path).read_text())
        packings = summary.get("packings", 1)
        scatter = summary.get("packing_std")
        model_error = summary["model_error_std"]
        parts += [
            f"### Parameter recovery on synthetic DEM targets ({summary['dataset']})",
            "",
            f"{summary['n_cases']} targets of the dataset's column with known (mu, e) not in its training set, "
            f"each the mean runout of {packings} DEM packing(s) (as a lab averages repeated tests) at t/t* = "
            f"{', '.join(f'{t:g}' for t in summary['t_over_tstar'])} plus Gaussian noise "
            f"(std {summary['noise_std']:g}). "
            + (
                f"The runout scatters between packings by {min(scatter):.2g}-{max(scatter):.2g} L* (pooled, "
                f"{summary['packing_dof']} dof); the posterior's noise holds the noise, that scatter / "
                f"sqrt({packings}) on the target side and the scatter of the one packing the GNS rolls out"
                if scatter
                else "The posterior's noise holds the noise"
            )
            + (
                ""
                if model_error is None
                else f", and the GNS's own runout error on its test split at each point, "
                f"{min(model_error):.2g}-{max(model_error):.2g}"
            )
            + f". mu within {summary['mu_tolerance']:g}: "
            f"**{summary['mu_within']} of {summary['n_cases']}**; truth inside both 95% intervals: "
            f"**{summary['truth_inside_95']} of {summary['n_cases']}** (target: all, and 4 of 5).",
            "",
            "| target | true mu, e | recovered mu, e | 95% interval mu | 95% interval e | identifiable | mu error |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in summary["cases"]:
            parts.append(
                f"| {r['target']} | {r['truth'][0]:.3f}, {r['truth'][1]:.3f} | {r['estimate'][0]:.3f}, "
                f"{r['estimate'][1]:.3f} | [{r['interval'][0][0]:.3f}, {r['interval'][0][1]:.3f}] | "
                f"[{r['interval'][1][0]:.3f}, {r['interval'][1][1]:.3f}] | "
                f"{', '.join('yes' if i else 'no' for i in r['identifiable'])} | {r['mu_error']:.3f} |"
            )
        parts += ["", f"![parameter recovery]({Path(os.path.relpath(figure, here)).as_posix()})", ""]
    return "\n".join(parts)


def write_section(
    names: Sequence[str],
    measured_paths: Sequence[StrPath],
    inverse_paths: Sequence[StrPath],
    table_paths: Sequence[StrPath],
    section_path: StrPath,
    recovery_paths: Sequence[StrPath] = (),
    recovery_figures: Sequence[StrPath] = (),
    *,
    bayesopt: bool = False,
) -> str:
    """Write results/report/inverse.md (atomically) and return its text: report_section with each
    column's figures beside its inverse.json (paths, deposits, runout, comparison.png, and
    bayesopt.png when the BO arm ran)."""
    figures = {}
    for name, result in zip(names, inverse_paths):
        folder = Path(result).parent
        figures[name] = {key: folder / f"{key}.png" for key in ("paths", "deposits", "runout", "comparison")}
        if bayesopt:
            figures[name]["bayesopt"] = folder / "bayesopt.png"
    text = report_section(
        names, measured_paths, inverse_paths, table_paths, figures, section_path, recovery_paths, recovery_figures
    )
    write_text(section_path, text)
    return text
