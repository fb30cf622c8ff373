"""The calibrated-model stage (workflow/rules/calibrated.smk): the answer to the user's question,
first in the report.

  - `run_calibrated` (rule calibrated): for one measured column, the model (config `calibration.model`,
    `auto`: the diagnosis' answer), its parameters by each route, every route validated by DEM runs
    on several packings -> results/calibrated/<name>/calibrated.json and calibrated.png;
  - `run_section` (rule calibrated_section): results/report/calibrated.md.

The methods are calibration/calibrated.py's.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from calibration.calibrated import (
    CALIBRATION_SEED,
    PREDICTION_TSTAR,
    bayesopt_model,
    diagnosis_parameters,
    predict,
    resolve_model,
    validate,
)
from calibration.design_runs import Model, SimulationSettings
from calibration.diagnosis_result import Diagnosis
from calibration.inverse import read_result
from calibration.measured import MeasuredColumn, expected_final_runout, load_column
from dem.atomic import StrPath, write_json, write_text
from dem.plots import save_figure
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from pipeline.diagnosis import read_diagnosis

log = logging.getLogger(__name__)
BASE = ("friction", "restitution")


def run_calibrated(
    measured_path: StrPath,
    diagnosis_path: StrPath | None,
    out_json: StrPath,
    out_figure: StrPath,
    out_prediction: StrPath,
    section: dict,
    diagnosis_section: dict,
    *,
    runout: dict | None,
    dem: dict | None,
    name: str = "",
    base_routes: dict[str, StrPath] | None = None,
) -> dict:
    """Calibrate and validate the model of one measured column (workflow rule calibrated).

    section: the config's `calibration` section (model, budget, n_initial, validation_packings, seed,
    finer_size_scale, predict_aspect_ratios); out_figure: the validation figure; out_prediction: the
    prediction across aspect ratios; diagnosis_section: the config's `diagnosis` section (its
    size_scale and channel width are the calibrated model's: parameters fitted at one scale are
    effective values of that scale);
    runout, dem: the config's runout and dem sections. base_routes: the paper's base-model routes of
    this column, {"inverse": inverse.json, "bayesopt": bayesopt.json, "doe": analysis.json} (any of
    them), whose optima are validated on the same packings, side by side (`base_route_optima`).
    """
    started = time.perf_counter()
    column = load_column(measured_path)
    diagnosis = read_diagnosis(diagnosis_path) if diagnosis_path else None
    model, why = resolve_model(section["model"], diagnosis, diagnosis_section["channel_width"])
    settings = SimulationSettings(size_scale=diagnosis_section["size_scale"])
    runout = RunoutMethod.from_config(runout)
    n_packings = section["validation_packings"]
    log.info("%s: calibrating %s (%s)", name, model.name, why)
    routes, answers = [], []  # every route validated; those that calibrate `model`
    if diagnosis is not None:
        # the diagnosis' own fits: the paper's model (mu, e) beside the calibrated one, when it is another
        runs = sum(diagnosis.simulator.design_runs.values()) + diagnosis.simulator.refinement_runs
        for route_model in [Model()] + ([model] if model.mechanism is not None else []):
            theta = diagnosis_parameters(diagnosis, route_model)
            route = f"{route_model.name}, diagnosis fit"
            routes.append(
                validate(route, route_model, column, theta, settings, runout, dem, n_packings, runs, diagnosis.seconds)
            )
            answers += [routes[-1]] if route_model == model else []
            log.info("%s: %s validated, MSE %.4g", name, route, routes[-1].mse)
    for route, theta, runs in base_route_optima(base_routes or {}):
        routes.append(validate(route, Model(), column, theta, settings, runout, dem, n_packings, runs))
        log.info("%s: %s validated, MSE %.4g", name, route, routes[-1].mse)
    bo_started = time.perf_counter()
    history = bayesopt_model(
        model,
        column,
        settings,
        runout,
        dem,
        budget=section["budget"],
        n_initial=section["n_initial"],
        seed=section["seed"],
        progress=progress_logger(f"BO of {model.name} on DEM runs of {name}", log),
    )
    theta, _ = history.best
    bo_seconds = time.perf_counter() - bo_started
    route = f"{model.name}, BO on DEM"
    routes.append(
        validate(route, model, column, theta, settings, runout, dem, n_packings, section["budget"], bo_seconds)
    )
    routes[-1].extra = {"history": history.to_dict()}
    answers.append(routes[-1])
    log.info("%s: BO optimum validated, MSE %.4g", name, routes[-1].mse)
    best = min(answers, key=lambda r: r.mse if math.isfinite(r.mse) else math.inf)
    theta = [best.parameters[parameter] for parameter in model.parameter_names]
    transfer = None
    if section["finer_size_scale"]:  # how far the answer transfers: the same validation with finer grains
        finer = SimulationSettings(size_scale=section["finer_size_scale"])
        transfer = validate(
            f"{best.route}, at size_scale {finer.size_scale:g}", model, column, theta, finer, runout, dem, n_packings
        )
        log.info("%s: at size_scale %g, MSE %.4g", name, finer.size_scale, transfer.mse)
    prediction = predict(model, column, theta, settings, section["predict_aspect_ratios"], runout, dem)
    result = {
        "name": name,
        "measured": str(measured_path),
        "column": column.name,
        "model": model.name,
        "parameters": list(model.parameter_names),
        "bounds": model.bounds.tolist(),
        "why": why,
        "answer": best.route,
        "routes": [r.to_dict() for r in routes],
        # 95% intervals of the model's parameters: the diagnosis' Laplace posterior (about its own fit)
        "intervals": None if diagnosis is None else model_intervals(diagnosis, model),
        "transfer": None if transfer is None else transfer.to_dict(),
        "prediction": prediction.to_dict(),
        "measured_final_runout": float(column.runout[-1]),
        "prediction_measured_a": column.aspect_ratio,
        "size_scale": settings.size_scale,
        "engine": (dem or {}).get("engine", "builtin"),
        "runout": runout.to_config(),
        "validation_packings": n_packings,
        "calibration_packing": CALIBRATION_SEED,
        "seconds": time.perf_counter() - started,
    }
    write_json(out_json, result)
    plot_calibrated(result, column, out_figure)
    plot_prediction(result, column, out_prediction)
    return result


def model_intervals(diagnosis: Diagnosis, model: Model) -> list[dict]:
    """[{name, value, std, low, high, identifiable, why}] of `model`'s parameters: the diagnosis'
    Laplace posterior of its emulator fit (calibration/uncertainty.py)."""
    evidence = diagnosis.base if model.mechanism is None else diagnosis.candidates[model.name]
    return [asdict(p) for p in evidence.emulator.posterior.parameters]


def base_route_optima(files: dict[str, StrPath]) -> list[tuple[str, list[float], int]]:
    """(route, (mu, e), DEM runs it spent) of each base-model route's optimum in `files`
    ({"inverse": inverse.json, "bayesopt": bayesopt.json, "doe": analysis.json}; DEM runs 0 where
    the route spent a GNS dataset's instead: the comparison section counts those)."""
    out = []
    if files.get("inverse"):
        data = read_result(files["inverse"])
        out.append(("base, GNS inverse design", [dict(zip(data["names"], data["best_params"]))[k] for k in BASE], 0))
    if files.get("doe"):
        data = json.loads(Path(files["doe"]).read_text())
        for model, fit in data["models"].items():
            out.append((f"base, DoE ({model})", [fit["optimum"]["natural"][k] for k in BASE], data["n_runs"]))
    if files.get("bayesopt"):
        data = json.loads(Path(files["bayesopt"]).read_text())
        best = dict(zip(data["names"], data["best_params"]))
        out.append(("base, BO on DEM", [best[k] for k in BASE], len(data["values"])))
    return out


# -- figure and report section -----------------------------------------------------------------------
def plot_calibrated(result: dict, column: MeasuredColumn, path: StrPath) -> None:
    """Measured points, each route's mean DEM curve over the validation packings with its packing
    band (mean +- one std) and the single packings as thin lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, route in enumerate(result["routes"]):
        colour = colours[k % len(colours)]
        t = np.array(route["t_over_tstar"])
        for curve in route["curves"]:
            if curve is not None:
                ax.plot(t, curve, color=colour, lw=0.6, alpha=0.4)
        mean, std = np.array(route["mean"]), np.array(route["std"])
        if np.isfinite(std).all():
            ax.fill_between(t, mean - std, mean + std, color=colour, alpha=0.15)
        n_ran = sum(c is not None for c in route["curves"])
        ax.plot(
            t, mean, color=colour, lw=2, label=f"{route['route']}: MSE {route['mse']:.3g} (mean of {n_ran} packings)"
        )
    ax.plot(column.t_over_tstar, column.runout, "ko", ms=6, label=f"measured ({column.name})")
    ax.set(
        xlabel="t / t*",
        ylabel="L* = (L - L_i) / L_i",
        title=f"{result['name']}: calibrated {result['model']} model, DEM at size_scale {result['size_scale']:g}",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)


def plot_prediction(result: dict, column: MeasuredColumn, path: StrPath) -> None:
    """Final runout L* and deposit height H_f / L_i of the calibrated model against the aspect ratio,
    the measured column's final L* on it, and the experimental scaling of Lube et al. (2005)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = result["prediction"]
    a = np.array(p["aspect_ratios"])
    runout = np.array([np.nan if v is None else v for v in p["final_runout"]])
    height = np.array([np.nan if v is None else v for v in p["height_over_L_i"]])
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    fine = np.linspace(max(a.min(), 0.1), a.max(), 100)
    left.plot(fine, [expected_final_runout(x) for x in fine], "k:", lw=1, label="Lube et al. (2005) scaling")
    left.plot(a, runout, "o-", color="tab:green", label=f"calibrated {result['model']} model (DEM)")
    measured = f"measured ({column.name}, at its last t/t*)"
    left.plot([column.aspect_ratio], [result["measured_final_runout"]], "ks", ms=8, label=measured)
    left.set(xlabel="aspect ratio a = H_i / L_i", ylabel="final runout L*", title="final runout")
    right.plot(a, height, "o-", color="tab:green")
    right.set(xlabel="aspect ratio a = H_i / L_i", ylabel="H_f / L_i", title="deposit height")
    for ax in (left, right):
        ax.grid(alpha=0.3)
    left.legend(fontsize=8)
    fig.suptitle(
        f"{result['name']}: predictions of the calibrated model (L_i = {column.L_i:g} m, size_scale "
        f"{result['size_scale']:g}, t/t* = {PREDICTION_TSTAR:g}, one packing each)",
        fontsize=10,
    )
    fig.tight_layout()
    save_figure(fig, path)


def section_markdown(results: Sequence[dict], section_path: StrPath) -> str:
    """The report's first section: the answer per measured column."""
    lines = [
        "The answer: which DEM model reproduces each measurement, its parameters, and how well DEM runs "
        "at them do, scored on the mean runout curve of several packings the calibration never saw "
        "(packing scatter beside it).",
        "",
    ]
    for result in results:
        answer = next(r for r in result["routes"] if r["route"] == result["answer"])
        figure = Path(os.path.relpath(Path(result["figure"]), Path(section_path).parent)).as_posix()
        parameters = ", ".join(f"{k} = {v:.3g}" for k, v in answer["parameters"].items())
        lines += [
            f"### {result['name']}: {result['model']} model",
            "",
            f"**{parameters}** (route: {answer['route']}), validated runout MSE **{answer['mse']:.3g}** "
            f"on the mean of {len(answer['seeds']) - len(answer['failed'])} packings "
            f"(each packing alone: {_span(answer['mse_each'])}).",
            "",
            f"Why this model: {result['why']}",
            "",
        ]
        if result.get("intervals"):
            spans = ", ".join(
                f"{p['name']} [{p['low']:.3g}, {p['high']:.3g}]" + ("" if p["identifiable"] else " (not identifiable)")
                for p in result["intervals"]
            )
            lines += [
                f"95% intervals (the diagnosis' Laplace posterior of this model, about its own fit): {spans}.",
                "",
            ]
        lines += [
            "| route | parameters | DEM runs to calibrate | time to calibrate | validated MSE (packing mean) | "
            "MSE per packing | failed runs | validation time |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for route in result["routes"]:
            values = ", ".join(f"{k} {v:.3g}" for k, v in route["parameters"].items())
            failed = "; ".join(f"packing {k}: {v}" for k, v in route["failed"].items()) or "none"
            runs = route["dem_runs"] or "those of the GNS dataset"
            lines.append(
                f"| {route['route']} | {values} | {runs} | {route['calibration_seconds']:.0f} s | "
                f"{route['mse']:.4g} | {_span(route['mse_each'])} | {failed} | {route['seconds']:.0f} s |"
            )
        lines += [
            "",
            f"DEM: {result['engine']} engine, size_scale {result['size_scale']:g} (parameters fitted at one scale are "
            f"effective values of that scale), runout read by {result['runout']['method']}; the Bayesian "
            f"optimisation ran on packing seed {result['calibration_packing']}, the validation on "
            f"{result['validation_packings']} others. The answer is the route of this model with the lower "
            "validated MSE (so the choice, not each route's score, has seen the validation packings); the "
            "diagnosis fit's time is the diagnosis job's, its design runs' DEM time aside.",
            "",
            f"![calibrated model of {result['name']}]({figure})",
            "",
        ]
        transfer = result["transfer"]
        if transfer is not None:
            verdict = (
                "the answer transfers."
                if transfer["mse"] <= 2 * answer["mse"]
                else "the parameters are effective values of their scale: recalibrate at the scale you run."
            )
            lines += [
                f"**Scale transfer.** The same parameters one size_scale finer ({transfer['route']}): validated "
                f"MSE **{transfer['mse']:.3g}** (each packing {_span(transfer['mse_each'])}) against "
                f"{answer['mse']:.3g} at size_scale {result['size_scale']:g}: {verdict}",
                "",
            ]
        p = result["prediction"]
        cells = [f"{v:.3g}" if v is not None else "failed" for v in p["final_runout"]]
        heights = [f"{v:.3g}" if v is not None else "failed" for v in p["height_over_L_i"]]
        lines += [
            "**Prediction** (same material, L_i and scale; one packing each): final runout at t/t* = "
            f"{PREDICTION_TSTAR:g} and deposit height by aspect ratio; the measured column (a = "
            f"{result['prediction_measured_a']:g}) reached L* = {result['measured_final_runout']:.3g} by its "
            "last time.",
            "",
            "| a | " + " | ".join(f"{a:g}" for a in p["aspect_ratios"]) + " |",
            "| --- |" + " --- |" * len(p["aspect_ratios"]),
            "| final L* | " + " | ".join(cells) + " |",
            "| H_f / L_i | " + " | ".join(heights) + " |",
            "",
            f"![predictions of {result['name']}]({Path(figure).with_name('prediction.png').as_posix()})",
            "",
        ]
    return "\n".join(lines) + "\n"


def _span(values: Sequence[float]) -> str:
    finite = [v for v in values if math.isfinite(v)]
    return f"{min(finite):.3g}-{max(finite):.3g}" if finite else "none ran"


def run_section(json_paths: Sequence[StrPath], figure_paths: Sequence[StrPath], section_path: StrPath) -> None:
    """results/report/calibrated.md from every calibrated.json (workflow rule calibrated_section)."""
    results = []
    for path, figure in zip(json_paths, figure_paths, strict=True):
        data = json.loads(Path(path).read_text())
        data["figure"] = str(figure)
        results.append(data)
    write_text(section_path, section_markdown(results, section_path))
