"""The calibrated-model stage (workflow/rules/calibrated.smk): the answer to the user's question,
first in the report.

  - `run_calibrated` (rule calibrated): for one measured column, the model (config `calibration.model`,
    `auto`: the diagnosis' answer), its parameters by each route, every route validated by DEM runs
    on several packings -> results/calibrated/<name>/calibrated.json and calibrated.png;
  - the other routes' jobs of the model: `run_model_bayesopt` (BO on DEM), `choose_model` (which
    model), `run_validation` (every route's optimum on the validation packings).

Its report section: pipeline/calibrated_section.py. The methods are calibration/calibrated.py's.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calibration.answer_choice import choose_answer, gns_versus_doe
from calibration.calibrated import (
    CALIBRATION_SEED,
    CalibrationError,
    bayesopt_model,
    calibration_box,
    diagnosis_parameters,
    model_record,
    mse_jackknife,
    resolve_model,
    validate,
)
from calibration.calibrated_result import CalibratedResult
from calibration.compare import plot_bayesopt
from calibration.confirmation import confirm, refine
from calibration.contenders import ContenderChoice, resolve_by_prediction
from calibration.diagnosis_result import Diagnosis
from calibration.inverse_result import read_result
from calibration.measured import read_measured
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import plausible_for
from calibration.model import Model
from calibration.prediction import PREDICTION_TSTAR, predict
from calibration.scaling_laws import DISC_2D_SOURCE, QUASI_2D_SOURCE, disc_2d_runout, quasi_2d_height, quasi_2d_runout
from calibration.target_scale import calibrate_at_target, plot_scales
from dem.atomic import StrPath, write_json
from dem.plots import save_figure
from dem.progress import progress_logger
from dem.run_store import keeps_runs
from pipeline.benchmarks import benchmark_seconds
from pipeline.calibrated_column import CalibratedColumn
from pipeline.diagnosis import read_diagnosis

if TYPE_CHECKING:
    from matplotlib.axes import Axes

log = logging.getLogger(__name__)
BASE = ("friction", "restitution")


@keeps_runs("out_json")
def run_model_bayesopt(job: CalibratedColumn, out_json: StrPath, out_figure: StrPath, section: dict) -> dict:
    """The Bayesian-optimisation route of the model of one measured column (workflow rule
    calibrated_bayesopt): section["budget"] DEM runs on packing CALIBRATION_SEED + section["seed"] ->
    bayesopt.json (route, the optimum, the history of every run, dem_runs, seconds) and its figure
    (the runs in the (mu, e) plane, the best so far against the runs)."""
    started = time.perf_counter()
    model, name = job.model, job.name
    history = bayesopt_model(
        model,
        job.column,
        job.settings,
        job.runout,
        job.dem,
        budget=section["budget"],
        n_initial=section["n_initial"],
        seed=section["seed"],
        progress=progress_logger(f"BO of {model.name} on DEM runs of {name}", log),
    )
    theta, value = history.best
    result = {
        "name": name,
        "route": f"{model.name}, BO on DEM",
        "parameters": list(model.parameter_names),
        "optimum": dict(zip(model.parameter_names, map(float, theta))),
        "value": float(value),
        "dem_runs": history.n_calls,  # failed runs cost DEM time too
        "history": history.to_dict(),
        "seconds": time.perf_counter() - started,
    }
    write_json(out_json, result)
    plot_bayesopt(result["history"], out_figure, title=f"{name}: {result['route']}")
    return result


def choose_model(
    diagnosis_path: StrPath | None,
    out_json: StrPath,
    choice: str,
    channel_width: float,
    name: str = "",
    box: str = "diagnosis",
    contenders_path: StrPath | None = None,
    measured_path: StrPath | None = None,
    plausible_ranges: dict | None = None,
) -> dict:
    """model.json of one measured column (workflow rule calibrated_model): the config's choice
    (calibration.model), `auto` resolved by the diagnosis at diagnosis_path and, where
    contenders_path (contenders.json, run_contenders) is given, by what the contenders predict across
    a too (calibration.contenders), with the range its mechanism is calibrated in (calibration.box,
    calibration.calibrated.calibration_box), and the plausible range of its mechanism's parameter for
    the material of the column at measured_path (calibration.mechanisms.plausible_for over the
    config's calibration.plausible_ranges). Returns the record."""
    diagnosis = read_diagnosis(diagnosis_path) if diagnosis_path else None
    model, why = resolve_model(choice, diagnosis, channel_width)
    by_prediction = bool(contenders_path) and choice == "auto"
    if by_prediction:
        model, why = resolve_by_prediction(model, why, ContenderChoice.read(contenders_path), channel_width)
    boxed = calibration_box(model, diagnosis, box)
    for inside, whole in zip(boxed.mechanisms, model.mechanisms, strict=True):
        if inside.bounds != whole.bounds:
            why += (
                f" Calibrated in {inside.parameter} [{inside.bounds[0]:.3g}, {inside.bounds[1]:.3g}] "
                f"(calibration.box {box}: the diagnosis' 95% interval widened, of the whole range "
                f"[{whole.bounds[0]:g}, {whole.bounds[1]:g}])."
            )
    if boxed.mechanisms and measured_path is not None:
        # a campaign's columns are of one material (pipeline.config.campaign_names)
        material = next(iter(read_measured(measured_path).values())).material_properties.name
        boxed = Model(*(plausible_for(m, material, plausible_ranges or {}) for m in boxed.mechanisms))
    record = dict(model_record(boxed, why, name), scaling_check=by_prediction)
    write_json(out_json, record)
    return record


def gns_points(inverse: dict, names: Sequence[str]) -> tuple[list[list[float]], list[float]]:
    """(parameters [m, p] in the order of `names`, GNS objective [m]) of every point a GNS inverse
    design (its inverse.json, read) evaluated, over all its starts."""
    order = [inverse["names"].index(name) for name in names]
    points = [[p[k] for k in order] for start in inverse["starts"] for p in start["evaluations"]["params"]]
    values = [v for start in inverse["starts"] for v in start["evaluations"]["values"]]
    return points, values


def gns_response(inverse: dict, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray] | None:
    """(parameters [n, p] in the order of `names`, L* [n, K]) of every point a GNS inverse design
    (its inverse.json, read) rolled out; None where the file does not record them."""
    evaluated = inverse.get("evaluated")
    if not evaluated or not evaluated["points"]:
        return None
    order = [inverse["names"].index(name) for name in names]
    return np.asarray(evaluated["points"], float)[:, order], np.asarray(evaluated["runouts"], float)


def route_optimum(key: str, source: StrPath, model: Model) -> tuple[str, Model, list[float], int, float, dict]:
    """(route label, the model it calibrates, theta [p], DEM runs it spent, seconds it took, extra)
    of route `key` from its file `source`; extra: what the report shows beside the validation. DEM
    runs and seconds are 0 where the file does not hold them (the stage passes the route's
    benchmark files instead). The keys (workflow rule calibrated_validate, one job each):
      diagnosis-base, diagnosis-model  the diagnosis' own fits (diagnosis.json) of the paper's model and of the model
                                       (under the scaling check contenders.json, whose pairs it fitted itself)
      base-inverse, base-bayesopt      the paper's base-model routes (inverse/<name>/inverse.json, bayesopt.json)
      base-doe-<eq9|quadratic>         the paper's DoE (doe/<name>/analysis.json)
      model-inverse, model-bayesopt    the model's own routes (calibrated/<name>/*.json)
      model-doe, model-doe-ff          its DoE: face-centred CCD, 3-level full factorial (doe*.json)"""
    if key == "diagnosis-model" and Path(source).name == "contenders.json":  # auto chose among them
        choice = ContenderChoice.read(source)
        contender = choice.contender(model.name)
        theta = [contender.parameters[k] for k in model.parameter_names]
        runs, seconds = choice.diagnosis_runs, choice.diagnosis_seconds
        if contender.pair_fit is None:  # one mechanism: the diagnosis' own fit
            return f"{model.name}, diagnosis fit", model, theta, runs, seconds, {}
        fit = contender.pair_fit  # a pair: fitted from its member's diagnosis fit
        label = f"{model.name}, pair fit from {fit.start}'s diagnosis fit"
        return label, model, theta, runs + fit.dem_runs, seconds + fit.seconds, {}
    if key.startswith("diagnosis-"):
        diagnosis = read_diagnosis(source)
        route_model = Model() if key == "diagnosis-base" else model
        runs = diagnosis.simulator.dem_runs
        theta = diagnosis_parameters(diagnosis, route_model).tolist()
        return f"{route_model.name}, diagnosis fit", route_model, theta, runs, diagnosis.seconds, {}
    data = read_result(source) if key.endswith("-inverse") else json.loads(Path(source).read_text())
    if key.startswith("base-doe-"):
        surface = key.removeprefix("base-doe-")
        optimum = data["models"][surface]["optimum"]["natural"]
        return f"base, DoE ({surface})", Model(), [optimum[k] for k in BASE], data["n_runs"], 0.0, {}
    if key == "base-inverse":
        best = dict(zip(data["names"], data["best_params"]))
        return "base, GNS inverse design", Model(), [best[k] for k in BASE], 0, 0.0, {}
    if key == "base-bayesopt":
        best = dict(zip(data["names"], data["best_params"]))
        return "base, BO on DEM", Model(), [best[k] for k in BASE], data["dem_runs"], 0.0, {}
    names = model.parameter_names
    if key == "model-inverse":
        best = dict(zip(data["names"], data["best_params"]))
        extra = {
            "gns_objective": data["best_value"],
            "intervals": data["posterior"]["parameters"],
            # does the GNS see each parameter (calibration.sensitivity; None: not checked)
            "sensitivity": (data.get("sensitivity") or {}).get("parameters"),
        }
        return f"{model.name}, GNS inverse design", model, [best[k] for k in names], 0, 0.0, extra
    if key == "model-bayesopt":
        extra = {"history": data["history"]}
        return data["route"], model, [data["optimum"][k] for k in names], data["dem_runs"], data["seconds"], extra
    if key in ("model-doe", "model-doe-ff"):
        surface = data["models"]["quadratic"]
        extra = {
            "predicted_mse": surface["optimum"]["predicted"],
            "r_squared": surface["r_squared"],
            "lack_of_fit_p": surface["lack_of_fit"]["p_value"],
            "significant": [e["source"] for e in surface["effects"] if e["p_value"] < 0.05],
            "failures": data["failures"],
        }
        return data["route"], model, [data["optimum"][k] for k in names], data["dem_runs"], data["seconds"], extra
    raise CalibrationError(f"{source}: unknown calibration route {key!r}")


@keeps_runs("out_json")
def run_validation(
    job: CalibratedColumn, key: str, source: StrPath, out_json: StrPath, section: dict, cost: dict | None = None
) -> dict:
    """Validate one route's optimum of one measured column (workflow rule calibrated_validate):
    DEM runs at it on section["validation_packings"] packings no calibration used -> the
    Validation as JSON, with the route's key and the model it calibrates. cost: {"files":
    [benchmark TSV of the route's jobs], "dem_runs": n} where the route's own file does not say."""
    column, model, settings, reading, dem, name = job.column, job.model, job.settings, job.runout, job.dem, job.name
    label, route_model, theta, runs, seconds, extra = route_optimum(key, source, model)
    if cost and cost.get("files"):
        seconds = benchmark_seconds(cost["files"])[0]
    runs = (cost or {}).get("dem_runs") or runs
    if key == "model-inverse" and section.get("gns_confirm_candidates"):
        # the GNS's few best distinct points run by the DEM first: the DEM, not the GNS's bits, chooses
        inverse = read_result(source)
        points, values = gns_points(inverse, route_model.parameter_names)
        confirmation = confirm(
            route_model, column, points, values, settings, reading, dem,
            section["gns_confirm_candidates"], section["gns_confirm_packings"],
            progress_logger(f"{name}: {label}, its best points confirmed by DEM", log),
        )  # fmt: skip
        response = gns_response(inverse, route_model.parameter_names)
        if section.get("gns_refine_rounds") and response is not None:
            confirmation = refine(
                route_model, column, confirmation, *response, settings, reading, dem, section["gns_refine_rounds"],
                progress_logger(f"{name}: {label}, corrected by DEM along the GNS's slopes", log),
            )  # fmt: skip
        theta, runs = confirmation.theta, runs + confirmation.dem_runs
        seconds += confirmation.seconds
        extra["confirmation"] = confirmation.to_dict()
        log.info(
            "%s: DEM check of the GNS's best %d points and %d correction steps: MSE %s, chose %d",
            name, len(confirmation.candidates), len(confirmation.steps),
            [round(c.mse, 4) for c in confirmation.checked], confirmation.chosen + 1,
        )  # fmt: skip
    validation = validate(
        label,
        route_model,
        column,
        theta,
        settings,
        reading,
        dem,
        section["validation_packings"],
        runs,
        seconds,
        progress=progress_logger(f"{name}: {label} validated on {section['validation_packings']} packings", log),
    )
    validation.extra = extra
    result = dict(validation.to_dict(), key=key, model=route_model.name)
    if (cost or {}).get("own_dem_runs") is not None:  # the model's GNS route: its own dataset's runs
        result["own_dem_runs"] = cost["own_dem_runs"] + extra.get("confirmation", {}).get("dem_runs", 0)
    write_json(out_json, result)
    log.info("%s: %s at %s validated, MSE %.4g", name, label, np.round(theta, 4).tolist(), validation.mse)
    return result


@keeps_runs("out_json")
def run_calibrated(
    job: CalibratedColumn,
    validation_paths: Sequence[StrPath],
    diagnosis_path: StrPath | None,
    out_json: StrPath,
    out_figure: StrPath,
    out_prediction: StrPath,
    section: dict,
    out_scales: StrPath | None = None,
) -> CalibratedResult:
    """The answer for one measured column (workflow rule calibrated): of the validated routes
    (validation_paths, written by run_validation) those of the model (model.json) compete: those
    within 2 SE of the lowest validated MSE run on answer_packings packings in all (the first
    shared; calibration.answer_choice) and the lowest there is the answer; it is carried to
    target_size_scale (calibration.target_scale), validated again one size_scale finer than that
    and predicts other aspect ratios at the target. Returns the CalibratedResult it
    writes to out_json (calibration/calibrated_result.py).

    section: the config's `calibration` section (validation_packings, answer_packings (absent or not
    above validation_packings: no runoff), target_size_scale (null or the calibration's: none),
    target_packings, target_rounds, finer_size_scale, predict_aspect_ratios);
    diagnosis_path: diagnosis.json (its Laplace posterior of the model gives intervals) or None;
    out_scales: the figure of the answer across grain sizes (calibration.target_scale.plot_scales).
    """
    started = time.perf_counter()
    column, model, why, name = job.column, job.model, job.why, job.name
    settings, runout, dem = job.settings, job.runout, job.dem
    diagnosis = read_diagnosis(diagnosis_path) if diagnosis_path else None
    n_packings = section["validation_packings"]
    routes = [json.loads(Path(path).read_text()) for path in validation_paths]
    answers = [r for r in routes if r["model"] == model.name]
    if not answers:
        raise CalibrationError(
            f"{name}: no route calibrated the {model.name} model (routes: {[r['key'] for r in routes]})"
        )
    answer_packings = section.get("answer_packings") or n_packings
    label = f"{name}: the routes within 2 SE of the best, on {answer_packings} packings"
    best, scored = choose_answer(
        answers, model, column, settings, runout, dem, n_packings, answer_packings, progress_logger(label, log)
    )
    if scored:
        log.info("%s: on %d packings %s", name, answer_packings, {r["route"]: round(r["mse"], 4) for r in scored})
    theta = [best["parameters"][parameter] for parameter in model.parameter_names]
    log.info("%s: %s model, answer %s at %s (MSE %.4g)", name, model.name, best["route"], theta, best["mse"])
    target, at_target = None, settings
    if (section.get("target_size_scale") or settings.size_scale) < settings.size_scale:
        # the answer carried to the resolution it must hold at: coarse slopes, target level
        at_target = replace(settings, size_scale=section["target_size_scale"])
        carrying = progress_logger(f"{name}: the answer at size_scale {at_target.size_scale:g}", log)
        target = calibrate_at_target(
            model, column, theta, settings, at_target.size_scale, runout, dem, section["target_packings"],
            n_packings, section["target_rounds"], progress=carrying, finer_size_scale=section["finer_size_scale"],
        )  # fmt: skip
        theta = target.theta
        log.info("%s: at size_scale %g, %s: MSE %.4g", name, target.size_scale, theta, target.validation.mse)
    transfer = None
    if section["finer_size_scale"]:  # how far the answer transfers, held out: a validation with finer grains
        finer = replace(settings, size_scale=section["finer_size_scale"])
        # the parameters the two scales predict for the finer one where the answer was carried (no
        # run there chose them), else the answer's own
        carried = target is not None and target.finer is not None
        label = f"{best['route']}, {'predicted for' if carried else 'at'} size_scale {finer.size_scale:g}"
        finer_done = progress_logger(f"{name}: {label}", log)
        theta_finer = target.finer.theta if carried else theta
        transfer = validate(label, model, column, theta_finer, finer, runout, dem, n_packings, progress=finer_done)
        log.info("%s: at size_scale %g, MSE %.4g", name, finer.size_scale, transfer.mse)
    aspect_ratios = section["predict_aspect_ratios"]
    predicting = progress_logger(f"{name}: predictions at a = {', '.join(f'{a:g}' for a in aspect_ratios)}", log)
    prediction = predict(model, column, theta, at_target, aspect_ratios, runout, dem, progress=predicting)
    gns = next((r for r in routes if r["key"] == "model-inverse"), None)
    # every route against the answer, packing by packing (all validations share their seeds), and
    # so on the runoff's packings, where the routes the answer is not told apart from show
    winner = next((r for r in scored if r["key"] == best["key"]), None)
    for entries, answer in ((routes, best), (scored, winner)):
        for route in entries:
            difference = mse_jackknife(route["curves"], column.runout, answer["curves"])
            route["versus_answer"] = dict(zip(("mse_difference", "se"), difference))
    result = CalibratedResult(
        name=name,
        measured=str(job.measured_path),
        column=column.name,
        model=model.name,
        parameters=list(model.parameter_names),
        bounds=model.bounds.tolist(),
        why=why,
        plausible=[
            {"parameter": m.parameter, "range": list(m.plausible), "source": m.plausible_source}
            for m in model.mechanisms
        ]
        or None,
        answer=best["route"],
        routes=routes,
        # the routes not told apart from the best on the shared packings, on answer_packings (none: no runoff)
        runoff=scored,
        answer_packings=answer_packings if scored else n_packings,
        # 95% intervals of the model's parameters: the diagnosis' Laplace posterior (about its own fit)
        intervals=None if diagnosis is None else model_intervals(diagnosis, model),
        # ... and the GNS inverse design's (about its optimum, through the GNS, with its error as noise)
        gns_intervals=None if gns is None else gns["extra"]["intervals"],
        gns_sensitivity=None if gns is None else gns["extra"].get("sensitivity"),
        gns_vs_doe=gns_versus_doe(routes, scored, column.runout),
        target=None if target is None else target.to_dict(),
        transfer=None if transfer is None else dict(transfer.to_dict(), size_scale=section["finer_size_scale"]),
        prediction=prediction.to_dict(),
        prediction_size_scale=at_target.size_scale,
        measured_final_runout=float(column.runout[-1]),
        prediction_measured_a=column.aspect_ratio,
        size_scale=settings.size_scale,
        engine=(dem or {}).get("engine", "builtin"),
        runout=runout.to_config(),
        runout_stated=column.runout_method is not None,  # False: the file states none, the config's
        validation_packings=n_packings,
        calibration_packing=CALIBRATION_SEED + section.get("seed", 0),
        seconds=time.perf_counter() - started,
    )
    result.to_json(out_json)
    plot_calibrated(result, column, out_figure)
    plot_prediction(result, column, out_prediction)
    if out_scales is not None:
        plot_scales(column, best, settings.size_scale, result.target, result.transfer, out_scales)
    return result


def model_intervals(diagnosis: Diagnosis, model: Model) -> list[dict] | None:
    """[{name, value, std, low, high, identifiable, why}] of `model`'s parameters: the diagnosis'
    Laplace posterior of its emulator fit (calibration/uncertainty.py); None for a model the diagnosis
    did not fit (a pair)."""
    evidence = diagnosis.base if model.name == "base" else diagnosis.candidates.get(model.name)
    return None if evidence is None else [asdict(p) for p in evidence.emulator.posterior.parameters]


# -- figure and report section -----------------------------------------------------------------------
def plot_calibrated(result: CalibratedResult, column: MeasuredColumn, path: StrPath) -> None:
    """Measured points, each route's mean DEM curve over the validation packings with its packing
    band (mean +- one std) and the single packings as thin lines; beside it, when the answer was
    chosen by a runoff, each contender's MSE on the shared packings and on all of the runoff's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scored = result.runoff
    if scored:
        fig, (ax, side) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [2.3, 1]})
        plot_runoff(result, side)
    else:
        fig, ax = plt.subplots(figsize=(7.5, 4.8))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, route in enumerate(result.routes):
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
        title=f"{result.name}: calibrated {result.model} model, DEM at size_scale {result.size_scale:g}",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)


def plot_runoff(result: CalibratedResult, ax: Axes) -> None:
    """On `ax`: each runoff contender's MSE on the packings every route shared (open) and on all the
    runoff's (filled, +- its jackknife SE), the answer's in bold."""
    scored = result.runoff
    first = {r["route"]: r["mse"] for r in result.routes}
    y = np.arange(len(scored))
    ax.plot(
        [first[r["route"]] for r in scored],
        y,
        "o",
        mfc="none",
        color="grey",
        label=f"{scored[0]['shared_packings']} packings",
    )
    se = [r["mse_se"] if r["mse_se"] is not None else 0.0 for r in scored]
    ax.errorbar([r["mse"] for r in scored], y, xerr=se, fmt="o", color="tab:blue", capsize=3,
                label=f"{result.answer_packings} packings +- SE")  # fmt: skip
    ax.set_yticks(y, [r["route"].split(", ", 1)[-1] for r in scored], fontsize=8)
    for tick, r in zip(ax.get_yticklabels(), scored):
        tick.set_fontweight("bold" if r["route"] == result.answer else "normal")
    ax.set(xlabel="validated runout MSE", title="choosing the answer")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")


def plot_prediction(result: CalibratedResult, column: MeasuredColumn, path: StrPath) -> None:
    """Final runout L* and deposit height H_f / L_i of the calibrated model against the aspect ratio,
    the measured column's final L* on it, the experimental scaling of a quasi-2D channel and, for
    contrast, that of true-2D discs (calibration.scaling_laws)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = result.prediction
    a = np.array(p["aspect_ratios"])
    runout = np.array([np.nan if v is None else v for v in p["final_runout"]])
    height = np.array([np.nan if v is None else v for v in p["height_over_L_i"]])
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    fine = np.linspace(max(a.min(), 0.1), a.max(), 100)
    left.plot(fine, [quasi_2d_runout(x) for x in fine], "k:", lw=1, label=f"{QUASI_2D_SOURCE} (dry sand)")
    left.plot(fine, [disc_2d_runout(x) for x in fine], ":", color="tab:gray", lw=1, label=DISC_2D_SOURCE)
    left.plot(a, runout, "o-", color="tab:green", label=f"calibrated {result.model} model (DEM)")
    measured = f"measured ({column.name}, at its last t/t*)"
    left.plot([column.aspect_ratio], [result.measured_final_runout], "ks", ms=8, label=measured)
    left.set(xlabel="aspect ratio a = H_i / L_i", ylabel="final runout L*", title="final runout")
    right.plot(fine, [quasi_2d_height(x) for x in fine], "k:", lw=1)
    right.plot(a, height, "o-", color="tab:green")
    right.set(xlabel="aspect ratio a = H_i / L_i", ylabel="H_f / L_i", title="deposit height")
    for ax in (left, right):
        ax.grid(alpha=0.3)
    left.legend(fontsize=8)
    fig.suptitle(
        f"{result.name}: predictions of the calibrated model (L_i = {column.L_i:g} m, size_scale "
        f"{result.size_scale:g}, t/t* = {PREDICTION_TSTAR:g}, one packing each)",
        fontsize=10,
    )
    fig.tight_layout()
    save_figure(fig, path)
