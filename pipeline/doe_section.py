"""The report's section of the DoE (workflow rule doe_section): results/report/doe.md from every
measured column's analysis.json and responses.csv (pipeline/doe.py writes those), its design centre
and validation runs, and the runout before/after figure of each column, drawn here.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.measured import load_column
from calibration.measured_column import MeasuredColumn
from calibration.objective import objective, runout_mse
from dem.atomic import StrPath, write_text
from dem.runout import RunoutMethod, runout_at, runout_curve
from dem.trajectory import read_trajectory
from doe.plots import plot_runout_comparison
from doe.study import RUNOUT_PREFIX, read_responses
from pipeline.benchmarks import benchmark_seconds


def runout_table(measured: MeasuredColumn, curves: dict) -> str:
    """Markdown table of L* at the measured t/t*: measured row, then one row per simulated curve."""
    header = "| | " + " | ".join(f"{t:g}" for t in measured.t_over_tstar) + " | MSE |"
    lines = [
        header,
        "|" + "---|" * (len(measured.t_over_tstar) + 2),
        "| measured | " + " | ".join(f"{v:g}" for v in measured.runout) + " | |",
    ]
    for label, values in curves.items():
        lines.append(
            f"| {label} | "
            + " | ".join(f"{v:.2f}" for v in values)
            + f" | {runout_mse(np.asarray(values), measured.runout):.3f} |"
        )
    return "\n".join(lines)


def section(
    name: str,
    measured: MeasuredColumn,
    summary: dict,
    responses: pd.DataFrame,
    validation: dict,
    figures: dict,
    time_spent: dict,
    section_path: StrPath,
) -> str:
    """Markdown report section of one measured column's DoE (links relative to `section_path`).

    responses: the table of collect_responses (design runs, their MSE and L* columns).
    validation: {model: {"mse": float, "runout": [K], "friction": .., "restitution": ..}}.
    figures: {"surface": path, "runout": path}. time_spent: {"dem_jobs_s", "dem_jobs", "dem_integration_s",
    "analysis_s"}.
    """
    here = Path(section_path).parent
    rel = {k: Path(os.path.relpath(v, here)).as_posix() for k, v in figures.items()}
    pure = summary["pure_error"]
    best = summary["best_run"]
    columns = [f"{RUNOUT_PREFIX}{t:g}" for t in measured.t_over_tstar]
    last = responses[columns[-1]].to_numpy(float)  # NaN: a failed run (summary["failures"])
    lines = [
        f"### {name}: {measured.material}, a = {measured.aspect_ratio:g}, L_i = {measured.L_i:g} m",
        "",
        f"{summary['n_runs']} DEM runs ({_levels_text(summary)}); response: MSE of L* at t/t* = "
        f"{', '.join(f'{t:g}' for t in measured.t_over_tstar)} against `{measured.source}`.",
        f"Best design run: {best['run_id']} (mu = {best['friction']:g}, e = {best['restitution']:g}), "
        f"MSE = {best['mse']:.3f}. Pure error from the replicated centre (another packing seed): "
        f"SS = {pure['sum_sq']:.4g} on {pure['df']} df, std = {pure['std']:.3g} (with so few df a rough "
        "estimate of the run-to-run noise).",
        f"Simulated L* at t/t* = {measured.t_over_tstar[-1]:g} over the design: {np.nanmin(last):.2f} to "
        f"{np.nanmax(last):.2f} (measured {measured.runout[-1]:g}).",
        "",
    ]
    if summary.get("failed"):  # analyses written before failures were recorded have no such key
        lines[-1:-1] = [f"{summary['failures'][0].upper()}{summary['failures'][1:]}."]
    for model, fit in summary["models"].items():
        lof = fit["lack_of_fit"]
        opt = fit["optimum"]
        lines += [
            f"**{model}** model, R² = {fit['r_squared']:.3f} (adjusted {fit['r_squared_adj']:.3f}), "
            f"RMSE = {fit['rmse']:.3f}; lack of fit F = {lof['F']:.3g}, p = {lof['p_value']:.3g}",
            "",
            f"`{fit['expression']}`",
            "",
            "| Source | LogWorth | p-value |",
            "|---|---|---|",
        ]
        lines += [f"| {e['source']} | {e['logworth']:.3f} | {e['p_value']:.3g} |" for e in fit["effects"]]
        lines += [
            "",
            f"Optimum within bounds: mu = {opt['natural']['friction']:.3f}, "
            f"e = {opt['natural']['restitution']:.3f}; predicted MSE {opt['predicted']:.3f} "
            f"(95% CI {opt['ci_low']:.3f} to {opt['ci_high']:.3f}).",
        ]
        if opt["on_bound"]:
            lines.append(
                f"The optimum lies on the bound of {', '.join(opt['on_bound'])}: the best setting may be "
                "outside the design region."
            )
        if opt["predicted"] < 0:
            lines.append(
                "The surface predicts a negative MSE there, which no run can reach: the model "
                "extrapolates and its minimum is not a trustworthy calibration."
            )
        if model in validation:
            lines += [
                f"DEM validation run at this optimum: **MSE = {validation[model]['mse']:.3f}** "
                "against the measured runout."
            ]
        lines.append("")
    centre = responses.loc[
        (responses["x_friction"].abs() + responses["x_restitution"].abs() < 1e-9) & (responses["replicate"] == 0)
    ].iloc[0]
    best_row = responses.loc[responses["run_id"] == best["run_id"]].iloc[0]
    centre_label = f"design centre {centre['run_id']} (mu={centre['friction']:.2f}, e={centre['restitution']:.2f})"
    best_label = (
        f"best design run {best_row['run_id']} (mu={best_row['friction']:.2f}, e={best_row['restitution']:.2f})"
    )
    curves = {
        centre_label: centre[columns].to_numpy(float),
        best_label: best_row[columns].to_numpy(float),
    }
    curves.update(
        {
            f"validation at {label} optimum (mu={v['friction']:.2f}, e={v['restitution']:.2f})": v["runout"]
            for label, v in validation.items()
        }
    )
    lines += [
        "L* at the measured times (the paper reports MSE 0.17 at its DoE optimum for quartz):",
        "",
        runout_table(measured, curves),
        "",
        f"![response surfaces]({rel['surface']})",
        "",
        f"![runout before and after calibration]({rel['runout']})",
        "",
        f"Time spent: DEM jobs {time_spent['dem_jobs_s'] / 60:.1f} min over {time_spent['dem_jobs']} jobs "
        f"(time integration alone {time_spent['dem_integration_s'] / 60:.1f} min), regression and "
        f"optimisation {time_spent['analysis_s']:.2f} s.",
        "",
    ]
    return "\n".join(lines)


def report_section(
    names: list[str],
    measured_paths: Sequence[StrPath],
    analysis_paths: Sequence[StrPath],
    centre_paths: Sequence[StrPath],
    validation_paths: dict,
    runout_figures: Sequence[StrPath],
    benchmark_paths: Mapping,
    section_path: StrPath,
    *,
    runout: RunoutMethod | dict | str | None,
) -> str:
    """The DoE report section for every measured column `names[k]`; draws its runout figure.

    Per name k: measured_paths[k] (CSV), analysis_paths[k] (analysis.json, beside it the response
    surface figure response_surface.png), centre_paths[k] (trajectory of the design centre, the
    "before" curve), validation_paths[name] {model: trajectory path}, runout_figures[k] (written
    here), benchmark_paths[name] (Snakemake benchmark files of this DoE's DEM jobs). runout: the
    config's runout method, by which every L* here is read unless a column states its own
    (MeasuredColumn.runout_reading; responses read another way are refused).
    """
    configured, parts = runout, []
    for k, name in enumerate(names):
        measured = load_column(measured_paths[k])
        runout = measured.runout_reading(configured)
        summary = json.loads(Path(analysis_paths[k]).read_text())
        centre = read_trajectory(centre_paths[k])
        curves = {
            f"before: design centre (mu={float(centre.attrs['friction']):g}, "
            f"e={float(centre.attrs['restitution']):g}), MSE {objective(centre, measured, runout):.3f}": runout_curve(
                centre, runout
            )
        }
        validation, integration_s = {}, 0.0
        for model, path in validation_paths[name].items():
            trajectory = read_trajectory(path)
            validation[model] = {
                "mse": objective(trajectory, measured, runout),
                "runout": runout_at(trajectory, measured.t_over_tstar, runout).tolist(),
                "friction": float(trajectory.attrs["friction"]),
                "restitution": float(trajectory.attrs["restitution"]),
            }
            curves[
                f"after: {model} optimum (mu={validation[model]['friction']:.2f}, "
                f"e={validation[model]['restitution']:.2f}), MSE {validation[model]['mse']:.3f}"
            ] = runout_curve(trajectory, runout)
            integration_s += float(trajectory.attrs.get("wall_time_s", 0.0))
        plot_runout_comparison(
            measured, curves, runout_figures[k], title=f"DoE calibration of {name}: runout before and after"
        )
        responses = read_responses(Path(analysis_paths[k]).with_name("responses.csv"), runout)
        jobs_s, jobs = benchmark_seconds(benchmark_paths[name])
        time_spent = {
            "dem_jobs_s": jobs_s,
            "dem_jobs": jobs,
            "analysis_s": summary["analysis_time_s"],
            "dem_integration_s": integration_s + float(responses["dem_wall_time_s"].sum()),
        }
        figures = {"surface": Path(analysis_paths[k]).with_name("response_surface.png"), "runout": runout_figures[k]}
        parts.append(section(name, measured, summary, responses, validation, figures, time_spent, section_path))
    return "\n".join(parts)


def _levels_text(summary: dict) -> str:
    bounds = ", ".join(f"{name} in [{lo:g}, {hi:g}]" for name, (lo, hi) in summary["factors"].items())
    return f"full factorial, {bounds}, plus the replicated centre"


def write_section(
    names: list[str],
    measured_paths: Sequence[StrPath],
    analysis_paths: Sequence[StrPath],
    centre_paths: Sequence[StrPath],
    validation_files: Iterable,
    runout_figures: Sequence[StrPath],
    benchmark_paths: dict,
    section_path: StrPath,
    *,
    runout: RunoutMethod | dict | str | None,
) -> str:
    """Write the DoE report section (`section_path`, results/report/doe.md) and the runout
    before/after figure of every column (report_section). Returns the text.

    validation_files: the validation trajectories, results/doe/<name>/validation/<model>.h5.
    """
    validation = {n: {} for n in names}
    for path in validation_files:
        validation[Path(path).parent.parent.name][Path(path).stem] = path
    text = report_section(
        names,
        measured_paths,
        analysis_paths,
        centre_paths,
        validation,
        runout_figures,
        benchmark_paths,
        section_path,
        runout=runout,
    )
    write_text(section_path, text)
    return text
