"""The DoE calibration study of one measured column: design rows for the DEM stage, responses from
the DEM runs, the analysis, the validation case at each model's optimum, and the report section.

Workflow scripts call these functions one each (workflow/rules/doe.smk); logic lives here.
"""
from __future__ import annotations

import csv
import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.objective import check_same_column, objective, runout_mse
from dem.atomic import atomic_path, write_text
from calibration.measured import load_column
from dem.runout import RunoutMethod, check_same_method, runout_at, runout_curve
from dem.trajectory import read_trajectory
from doe.design import design_cases
from doe.plots import plot_runout_comparison
from doe.regression import analyse, prediction_expression

RUNOUT_PREFIX = "L_star_t"  # response columns L_star_t0.5, ... : simulated L* at the measured t/t*
RUNOUT_METHOD_COLUMN = "runout_method"   # the runout method (JSON) every response was read by


def case_rows(design: pd.DataFrame, measured, dataset: str, **case_fields) -> list[dict]:
    """Case-table rows (dem.grid format) of every design run, for the DEM stage's rules.

    dataset: the case-table dataset name of this study (e.g. "doe_quartz"); case_id = run_id.
    case_fields: CollapseCase fields shared by every run (size_scale, duration_over_tstar, ...).
    Each row is checked by building its CollapseCase.
    """
    rows = []
    for run_id, case in design_cases(design, measured, **case_fields).items():
        row = {"dataset": dataset, "case_id": run_id, "split": "doe", "material": case.material.name,
               "L_i": case.column_length, "aspect_ratio": case.aspect_ratio, "friction": case.friction,
               "restitution": case.restitution, "seed": case.seed, "output_interval": case.output_interval}
        row.update(case_fields)
        rows.append(row)
    return rows


def collect_responses(design: pd.DataFrame, trajectory_paths: dict, measured, runout: RunoutMethod) -> pd.DataFrame:
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
        record = {"run_id": run_id, "mse": runout_mse(values, measured.runout),
                  "dem_wall_time_s": float(trajectory.attrs.get("wall_time_s", math.nan)),
                  RUNOUT_METHOD_COLUMN: json.dumps(runout.to_config(), sort_keys=True)}
        record.update({f"{RUNOUT_PREFIX}{t:g}": float(v) for t, v in zip(measured.t_over_tstar, values)})
        records.append(record)
    return design.merge(pd.DataFrame(records), on="run_id")


def run_analysis(responses: pd.DataFrame, factors, models) -> tuple[dict, dict]:
    """analyse() with the prediction expressions and the analysis time added to the summary."""
    start = time.perf_counter()
    fits, summary = analyse(responses, factors, "mse", models)
    for model, fit in fits.items():
        summary["models"][model]["expression"] = prediction_expression(fit)
    summary["analysis_time_s"] = time.perf_counter() - start
    return fits, summary


def write_json(path, data) -> None:
    write_text(path, json.dumps(data, indent=1, default=_plain) + "\n")


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def validation_case(summary: dict, model: str, measured, **case_fields):
    """The DEM case at `model`'s optimum (analysis summary from run_analysis) on the measured column."""
    if model not in summary["models"]:
        raise KeyError(f"model {model!r} not in the analysis; fitted: {list(summary['models'])}")
    optimum = summary["models"][model]["optimum"]["natural"]
    return measured.collapse_case(**optimum, name=f"doe_validation_{model}", **case_fields)


def runout_table(measured, curves: dict) -> str:
    """Markdown table of L* at the measured t/t*: measured row, then one row per simulated curve."""
    header = "| | " + " | ".join(f"{t:g}" for t in measured.t_over_tstar) + " | MSE |"
    lines = [header, "|" + "---|" * (len(measured.t_over_tstar) + 2),
             "| measured | " + " | ".join(f"{v:g}" for v in measured.runout) + " | |"]
    for label, values in curves.items():
        lines.append(f"| {label} | " + " | ".join(f"{v:.2f}" for v in values)
                     + f" | {runout_mse(np.asarray(values), measured.runout):.3f} |")
    return "\n".join(lines)


def benchmark_seconds(paths) -> tuple[float, int]:
    """(total seconds, jobs) over the Snakemake benchmark files among `paths` that exist."""
    total, jobs = 0.0, 0
    for path in map(Path, paths):
        if path.is_file():
            with open(path, newline="") as handle:
                for row in csv.DictReader(handle, delimiter="\t"):
                    total += float(row["s"])
                    jobs += 1
    return total, jobs


def section(name: str, measured, summary: dict, responses: pd.DataFrame, validation: dict, figures: dict,
            time_spent: dict, section_path) -> str:
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
    last = responses[columns[-1]].to_numpy(float)
    lines = [f"### {name}: {measured.material}, a = {measured.aspect_ratio:g}, L_i = {measured.L_i:g} m",
             "",
             f"{summary['n_runs']} DEM runs ({_levels_text(summary)}); response: MSE of L* at t/t* = "
             f"{', '.join(f'{t:g}' for t in measured.t_over_tstar)} against `{measured.source}`.",
             f"Best design run: {best['run_id']} (mu = {best['friction']:g}, e = {best['restitution']:g}), "
             f"MSE = {best['mse']:.3f}. Pure error from the replicated centre (another packing seed): "
             f"SS = {pure['sum_sq']:.4g} on {pure['df']} df, std = {pure['std']:.3g} (with so few df a rough "
             "estimate of the run-to-run noise).",
             f"Simulated L* at t/t* = {measured.t_over_tstar[-1]:g} over the design: {last.min():.2f} to "
             f"{last.max():.2f} (measured {measured.runout[-1]:g}).", ""]
    for model, fit in summary["models"].items():
        lof = fit["lack_of_fit"]
        opt = fit["optimum"]
        lines += [f"**{model}** model, R² = {fit['r_squared']:.3f} (adjusted {fit['r_squared_adj']:.3f}), "
                  f"RMSE = {fit['rmse']:.3f}; lack of fit F = {lof['F']:.3g}, p = {lof['p_value']:.3g}", "",
                  f"`{fit['expression']}`", "",
                  "| Source | LogWorth | p-value |", "|---|---|---|"]
        lines += [f"| {e['source']} | {e['logworth']:.3f} | {e['p_value']:.3g} |" for e in fit["effects"]]
        lines += ["", f"Optimum within bounds: mu = {opt['natural']['friction']:.3f}, "
                      f"e = {opt['natural']['restitution']:.3f}; predicted MSE {opt['predicted']:.3f} "
                      f"(95% CI {opt['ci_low']:.3f} to {opt['ci_high']:.3f})."]
        if opt["on_bound"]:
            lines.append(f"The optimum lies on the bound of {', '.join(opt['on_bound'])}: the best setting may be "
                         "outside the design region.")
        if opt["predicted"] < 0:
            lines.append("The surface predicts a negative MSE there, which no run can reach: the model "
                         "extrapolates and its minimum is not a trustworthy calibration.")
        if model in validation:
            lines += [f"DEM validation run at this optimum: **MSE = {validation[model]['mse']:.3f}** "
                      "against the measured runout."]
        lines.append("")
    centre = responses.loc[(responses["x_friction"].abs() + responses["x_restitution"].abs() < 1e-9)
                           & (responses["replicate"] == 0)].iloc[0]
    best_row = responses.loc[responses["run_id"] == best["run_id"]].iloc[0]
    curves = {f"design centre {centre['run_id']} (mu={centre['friction']:.2f}, e={centre['restitution']:.2f})":
              centre[columns].to_numpy(float),
              f"best design run {best_row['run_id']} (mu={best_row['friction']:.2f}, e={best_row['restitution']:.2f})":
              best_row[columns].to_numpy(float)}
    curves.update({f"validation at {label} optimum (mu={v['friction']:.2f}, e={v['restitution']:.2f})": v["runout"]
                   for label, v in validation.items()})
    lines += ["L* at the measured times (the paper reports MSE 0.17 at its DoE optimum for quartz):", "",
              runout_table(measured, curves), "",
              f"![response surfaces]({rel['surface']})", "",
              f"![runout before and after calibration]({rel['runout']})", "",
              f"Time spent: DEM jobs {time_spent['dem_jobs_s'] / 60:.1f} min over {time_spent['dem_jobs']} jobs "
              f"(time integration alone {time_spent['dem_integration_s'] / 60:.1f} min), regression and "
              f"optimisation {time_spent['analysis_s']:.2f} s.", ""]
    return "\n".join(lines)


def report_section(names, measured_paths, analysis_paths, centre_paths, validation_paths: dict, runout_figures,
                   benchmark_paths: dict, section_path, *, runout) -> str:
    """The DoE report section for every measured column `names[k]`; draws its runout figure.

    Per name k: measured_paths[k] (CSV), analysis_paths[k] (analysis.json, beside it the response
    surface figure response_surface.png), centre_paths[k] (trajectory of the design centre, the
    "before" curve), validation_paths[name] {model: trajectory path}, runout_figures[k] (written
    here), benchmark_paths[name] (Snakemake benchmark files of this DoE's DEM jobs). runout: the
    config's runout method, by which every L* here is read (responses read another way are refused).
    """
    runout = RunoutMethod.from_config(runout)
    parts = []
    for k, name in enumerate(names):
        measured = load_column(measured_paths[k])
        summary = json.loads(Path(analysis_paths[k]).read_text())
        centre = read_trajectory(centre_paths[k])
        curves = {f"before: design centre (mu={float(centre.attrs['friction']):g}, "
                  f"e={float(centre.attrs['restitution']):g}), MSE {objective(centre, measured, runout):.3f}":
                  runout_curve(centre, runout)}
        validation, integration_s = {}, 0.0
        for model, path in validation_paths[name].items():
            trajectory = read_trajectory(path)
            validation[model] = {"mse": objective(trajectory, measured, runout),
                                 "runout": runout_at(trajectory, measured.t_over_tstar, runout).tolist(),
                                 "friction": float(trajectory.attrs["friction"]),
                                 "restitution": float(trajectory.attrs["restitution"])}
            curves[f"after: {model} optimum (mu={validation[model]['friction']:.2f}, "
                   f"e={validation[model]['restitution']:.2f}), MSE {validation[model]['mse']:.3f}"] = \
                runout_curve(trajectory, runout)
            integration_s += float(trajectory.attrs.get("wall_time_s", 0.0))
        plot_runout_comparison(measured, curves, runout_figures[k],
                               title=f"DoE calibration of {name}: runout before and after")
        responses = read_responses(Path(analysis_paths[k]).with_name("responses.csv"), runout)
        jobs_s, jobs = benchmark_seconds(benchmark_paths[name])
        time_spent = {"dem_jobs_s": jobs_s, "dem_jobs": jobs, "analysis_s": summary["analysis_time_s"],
                      "dem_integration_s": integration_s + float(responses["dem_wall_time_s"].sum())}
        figures = {"surface": Path(analysis_paths[k]).with_name("response_surface.png"), "runout": runout_figures[k]}
        parts.append(section(name, measured, summary, responses, validation, figures, time_spent, section_path))
    return "\n".join(parts)


def _levels_text(summary: dict) -> str:
    bounds = ", ".join(f"{name} in [{lo:g}, {hi:g}]" for name, (lo, hi) in summary["factors"].items())
    return f"full factorial, {bounds}, plus the replicated centre"


def read_responses(path, runout: RunoutMethod) -> pd.DataFrame:
    """responses.csv of collect_responses; RunoutError when it was read by another runout method."""
    table = pd.read_csv(path)
    runout = RunoutMethod.from_config(runout)
    methods = set(table[RUNOUT_METHOD_COLUMN].fillna("")) if RUNOUT_METHOD_COLUMN in table else {""}
    for found in methods:
        check_same_method(json.loads(found) if found else None, runout, f"DoE responses {path}")
    return table


def write_responses(path, responses: pd.DataFrame) -> None:
    with atomic_path(path) as tmp:
        responses.to_csv(tmp, index=False)
