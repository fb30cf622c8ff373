"""The inverse-design stage: what each job of workflow/rules/inverse.smk does, and the stage's
report section (results/report/inverse.md).

Per measured column: a DEM run at the start point and one at the GNS optimum (run_dem_at), the
GNS inverse design (run_inverse_design), Bayesian optimisation directly on DEM runs
(run_bayesopt), the comparison of the calibration routes (run_comparison); per dataset: the
parameter recovery of synthetic DEM targets (run_recovery); then the section
(write_section). The methods live in calibration.compare, calibration.inverse (with
calibration.gns_objective, calibration.lbfgsb and calibration.inverse_plots) and
calibration.recovery; here they meet the pipeline's files: inputs read, outputs written
atomically, progress logged. Times of the routes come from the Snakemake benchmark files
(pipeline.benchmarks).
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

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
from calibration.gns_objective import GNSObjective
from calibration.inverse import InverseResult, inverse_design, read_result, write_result
from calibration.inverse_plots import plot_deposits, plot_paths
from calibration.measured import MeasuredColumn, load_column
from calibration.objective import objective
from calibration.recovery import plot_recovery, recovery_study
from dem.atomic import StrPath, write_json, write_text
from dem.progress import progress_logger
from dem.runout import RunoutMethod, check_same_method, runout_curve
from dem.trajectory import read_trajectory, write_trajectory
from gns.data import read_metadata, read_training_attrs
from gns.simulator import load_simulator
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
def model_error_from_evaluation(path: StrPath | None, runout: RunoutMethod) -> float | None:
    """RMS runout error (L*) of the GNS against the DEM on its test split (gns.evaluate's summary),
    which must have been read by the same runout method."""
    if not path:
        return None
    summary = json.loads(Path(path).read_text())
    check_same_method(summary.get("runout"), runout, f"GNS evaluation {path}")
    value = summary.get("runout_mse")
    return math.sqrt(value) if value is not None and math.isfinite(value) else None


def run_inverse_design(
    model_path: StrPath,
    metadata_path: StrPath,
    start_path: StrPath | Sequence[StrPath],
    measured_path: StrPath,
    out_json: StrPath,
    out_paths: StrPath,
    out_deposits: StrPath,
    settings: dict,
    *,
    runout: dict | None,
    evaluation_path: StrPath | None = None,
    doe_responses_path: StrPath | None = None,
    threads: int | None = None,
    design_names: Sequence[str] = START_NAMES,
    start_values: dict | None = None,
    optimiser: dict | None = None,
    dataset_paths: Sequence[StrPath] = (),
) -> InverseResult:
    """The inverse-design stage of one measured column: inverse.json and the two figures.
    start_path: the start run, or several packings of the column (GNSObjective's starts).

    settings: the config's `inverse` section (friction, restitution bounds, start, starts, gradient,
    fd_step, max_iterations, landscape_levels, seed); runout: the config's `runout` section (every L*
    is read by it). evaluation_path: the GNS's test-split summary
    (its runout error joins the noise model); doe_responses_path: the DoE's DEM objective values,
    drawn under the paths. threads: torch's CPU threads (the job's; None: torch's default).
    design_names: the parameters designed (the GNS's inputs; bounds from settings[name], else the
    range the GNS was trained on); start_values: {name: value} of the start run that its file does
    not record (the start run of the base model has a mechanism at its off value), also the first
    start of a parameter beyond inverse.start. optimiser: {"optimiser": "lbfgsb" | "bayesopt",
    "budget", "n_initial"} (calibration.inverse.inverse_design's; None: the paper's L-BFGS-B).
    dataset_paths: the DEM runs of the GNS's dataset, against which the GNS's response to each
    design parameter is checked (calibration.sensitivity; none: no check).
    """
    if threads:
        torch.set_num_threads(threads)
    metadata = read_metadata(metadata_path)
    simulator = load_simulator(model_path, metadata)
    measured = load_column(measured_path)
    paths = [start_path] if isinstance(start_path, (str, os.PathLike)) else list(start_path)
    starts = [read_trajectory(path) for path in paths]
    for packing in starts:  # a start run of the base model records no mechanism parameter
        packing.attrs = {**(start_values or {}), **packing.attrs}
    # the GNS's test-split error was read by the config's method; the design reads the column's way
    model_error = model_error_from_evaluation(evaluation_path, RunoutMethod.from_config(runout))
    runout = measured.runout_reading(runout)
    first_start = dict(zip(START_NAMES, settings["start"]))
    result = inverse_design(
        simulator,
        starts,
        measured,
        metadata,
        read_training_attrs(metadata),
        bounds=[settings.get(name) for name in design_names],
        n_starts=settings["starts"],
        first_start=[first_start.get(name, (start_values or {}).get(name)) for name in design_names],
        gradient=settings["gradient"],
        fd_step=settings["fd_step"],
        max_iterations=settings["max_iterations"],
        model_error_std=model_error,
        landscape_levels=settings["landscape_levels"] if len(design_names) == 2 else 0,
        seed=settings["seed"],
        design_names=design_names,
        runout=runout,
        reference=dataset_runs(dataset_paths, design_names, measured, runout) if dataset_paths else None,
        **(optimiser or {}),
    )
    write_result(result, out_json)
    dem_points = None
    if doe_responses_path:
        from doe.study import read_responses  # the DoE's DEM points drawn under the paths

        table = read_responses(doe_responses_path, runout)
        dem_points = {name: table[name].to_numpy(float) for name in list(result.names) + ["mse"]}
    plot_paths(result.to_dict(), out_paths, dem_points)
    best = min(result.starts, key=lambda r: r.value)
    middle = best.iterates[len(best.iterates) // 2][0]
    plot_deposits(
        GNSObjective(simulator, starts[0], measured, result.names, runout=runout),
        {"start": best.start, f"iteration {len(best.iterates) // 2}": middle, "optimum": best.params},
        out_deposits,
    )
    return result


def dataset_runs(
    paths: Sequence[StrPath], names: Sequence[str], measured: MeasuredColumn, runout: RunoutMethod
) -> tuple[np.ndarray, np.ndarray]:
    """(parameters [n, P] in the order of names, L* [n, K] at the measured t/t*) of the DEM runs at
    paths (a GNS's dataset), each read by `runout`."""
    runs = [read_trajectory(path) for path in paths]
    points = np.array([[float(run.attrs[name]) for name in names] for run in runs])
    return points, np.array([runout.at(run, measured.t_over_tstar) for run in runs])


def run_recovery(
    model_path: StrPath,
    metadata_path: StrPath,
    out_json: StrPath,
    out_figure: StrPath,
    *,
    runout: dict | None,
    evaluation_path: StrPath | None = None,
    dem: dict | None = None,
    threads: int | None = None,
    **study_kwargs: Any,
) -> dict:
    """The recovery stage: recovery_study with the GNS at model_path, L* read by `runout` (the
    config's runout section), DEM runs by the engine of `dem` (the config's dem section); writes
    JSON and figure. threads: torch's CPU threads (the job's; None: torch's default)."""
    if threads:
        torch.set_num_threads(threads)
    metadata = read_metadata(metadata_path)
    runout = RunoutMethod.from_config(runout)
    summary = recovery_study(
        load_simulator(model_path, metadata),
        metadata,
        model_error_std=model_error_from_evaluation(evaluation_path, runout),
        runout=runout,
        dem_config=dem,
        **study_kwargs,
    )
    write_json(out_json, summary)
    plot_recovery(
        summary,
        out_figure,
        title=f"{metadata['name']} (targets: mean of {summary['packings']} packings): mu "
        f"within {summary['mu_tolerance']:g} in {summary['mu_within']} of {summary['n_cases']}, truth inside "
        f"95% in {summary['truth_inside_95']}",
    )
    return summary


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
            + ("" if model_error is None else f", and the GNS's own runout error {model_error:.3g}")
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
