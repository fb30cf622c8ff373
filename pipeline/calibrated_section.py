"""The report's section of the calibrated model (workflow rule calibrated_section):
results/report/calibrated.md from every measured column's calibrated.json (pipeline/calibrated.py
writes those), and the answer's score as the report and the answer page (pipeline/answer.py) state it.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

from calibration.answer_choice import not_told_apart
from calibration.calibrated_result import CalibratedResult
from calibration.contenders import ContenderChoice
from calibration.prediction import PREDICTION_TSTAR
from calibration.scaling_laws import DISC_2D_SOURCE, QUASI_2D_SOURCE, check_scaling
from calibration.target_scale import resolution_shift
from dem.atomic import StrPath, write_text
from pipeline.contenders_section import contenders_lines, plausibility_lines, scaling_sentence


def answer_score(result: dict) -> dict:
    """The answer's score as the report states it, from calibrated.json `result`: {route, mse,
    mse_se, mse_each, seeds, curves, n_ran, shared} on the runoff's packings when the answer ran one
    (shared: the packings every route was scored on, with their MSE as shared_mse), else on the
    validation's."""
    answer = next(r for r in result["routes"] if r["route"] == result["answer"])
    scored = next((r for r in result.get("runoff") or [] if r["route"] == result["answer"]), None)
    source = scored or answer
    return {
        "route": answer,
        "mse": source["mse"],
        "mse_se": source.get("mse_se"),
        "mse_each": source["mse_each"],
        "seeds": source["seeds"],
        "curves": source["curves"],
        "n_ran": len(source["seeds"]) - len(source["failed"]),
        "shared": None if scored is None else len(answer["seeds"]) - len(answer["failed"]),
        "shared_mse": answer["mse"],
    }


def transfer_reference(result: dict, score: dict) -> tuple[float, float]:
    """(MSE, size_scale) the transfer is held against: the answer's validation at the target where
    calibrated.json `result` carried it there, else the answer's at its own scale on as many packings
    as the transfer (answer_score's shared_mse: a runoff's mean over more packings scores lower by
    its smaller scatter)."""
    if result.get("target"):
        return result["target"]["validation"]["mse"], result["target"]["size_scale"]
    return score["shared_mse"], result["size_scale"]


def transfer_holds(transfer: dict, reference_mse: float) -> bool:
    """Whether the answer transfers to finer grains (calibrated.json's `transfer`): its MSE there at
    most twice `reference_mse` (transfer_reference's)."""
    return transfer["mse"] <= 2 * reference_mse


def section_markdown(results: Sequence[dict], section_path: StrPath) -> str:
    """The report's first section: the answer per measured column."""
    lines = [
        "The answer: which DEM model reproduces each measurement, its parameters, and how well DEM runs "
        "at them do, scored on the mean runout curve of several packings the calibration never saw "
        "(packing scatter beside it).",
        "",
    ]
    for result in results:
        score = answer_score(result)
        figure = Path(os.path.relpath(Path(result["figure"]), Path(section_path).parent)).as_posix()
        lines += answer_lines(result, score)
        lines += target_lines(result, figure)
        lines += interval_lines(result)
        lines += routes_lines(result)
        lines += dem_lines(result, figure, section_path)
        lines += transfer_lines(result, score)
        lines += prediction_lines(result, figure)
    return "\n".join(lines) + "\n"


def answer_lines(result: dict, score: dict) -> list[str]:
    """The column's heading, the answer's parameters and validated score, their plausibility, the
    runoff and why this model."""
    answer = score["route"]
    parameters = ", ".join(f"{k} = {v:.3g}" for k, v in answer["parameters"].items())
    return [
        f"### {result['name']}: {result['model']} model",
        "",
        f"**{parameters}** (route: {answer['route']}), validated runout MSE **{score['mse']:.3g}** "
        f"+- {format_se(score['mse_se'])} on the mean of {score['n_ran']} packings "
        f"(each packing alone: {format_span(score['mse_each'])}).",
        "",
        *plausibility_lines(answer["parameters"], result.get("plausible")),
        *runoff_lines(result),
        f"Why this model: {result['why']}",
        "",
    ]


def interval_lines(result: dict) -> list[str]:
    """The 95% intervals of the diagnosis' and the GNS's posteriors, and every parameter the GNS does
    not see as the DEM does (calibration.sensitivity)."""
    lines = []
    if result.get("intervals"):
        spans = ", ".join(
            f"{p['name']} [{p['low']:.3g}, {p['high']:.3g}]" + ("" if p["identifiable"] else " (not identifiable)")
            for p in result["intervals"]
        )
        lines += [
            f"95% intervals (the diagnosis' Laplace posterior of this model, about its own fit): {spans}.",
            "",
        ]
    if result.get("gns_intervals"):
        spans = ", ".join(
            f"{p['name']} {p['value']:.3g} [{p['low']:.3g}, {p['high']:.3g}]"
            + ("" if p["identifiable"] else " (not identifiable)")
            for p in result["gns_intervals"]
        )
        lines += [
            f"95% intervals of the GNS inverse design (its Laplace posterior about the GNS optimum; noise: the "
            f"measured scatter and the GNS's own runout error on its test split at each t/t* point): {spans}.",
            "",
        ]
    for p in result.get("gns_sensitivity") or []:  # calibration.sensitivity: the GNS blind to a parameter
        if p["resolved"] is False:
            lines += [
                f"**The GNS does not see {p['name']}**: {p['why'].removeprefix('the GNS does not resolve it: ')}; "
                "the GNS route's value of it is a guess (figure: does the GNS see each parameter).",
                "",
            ]
        elif p.get("gns_only"):
            lines += [
                f"**The GNS responds to {p['name']}, the DEM hardly does**: "
                f"{p['why'].removeprefix('the DEM hardly responds to it, the GNS does: ')}; the GNS route's "
                "interval of it rests on the GNS alone (flagged not identifiable; figure: does the GNS see each "
                "parameter).",
                "",
            ]
    return lines


def routes_lines(result: dict) -> list[str]:
    """Every route of the model side by side (parameters, cost, validated score, paired difference),
    the GNS route held against each DoE route, and each route's own notes."""
    lines = [
        "| route | parameters | DEM runs to calibrate | time to calibrate | validated MSE (packing mean) +- SE | "
        "minus the answer's, paired +- SE | MSE per packing | failed runs | validation time |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for route in result["routes"]:
        values = ", ".join(f"{k} {v:.3g}" for k, v in route["parameters"].items())
        failed = "; ".join(f"packing {k}: {v}" for k, v in route["failed"].items()) or "none"
        runs = route["dem_runs"] or "those of the GNS dataset"
        versus = route.get("versus_answer") or {}
        lines.append(
            f"| {route['route']} | {values} | {runs} | {route['calibration_seconds']:.0f} s | "
            f"{route['mse']:.4g} +- {format_se(route.get('mse_se'))} | "
            f"{versus.get('mse_difference', math.nan):+.3g} +- {format_se(versus.get('se'))} | "
            f"{format_span(route['mse_each'])} | {failed} | {route['seconds']:.0f} s |"
        )
    lines += [
        "",
        "SE: the jackknife standard error over the validation packings (how far another "
        f"{result['validation_packings']} packings could move the score); the paired difference uses the "
        "same packings for both routes, so their shared chaos cancels. Routes whose difference is within "
        "about 2 SE of zero are not told apart by this validation.",
        "",
    ]
    for versus in result.get("gns_vs_doe") or []:
        if versus["se"] is None:
            verdict = "too few packings ran to tell them apart"
        elif abs(versus["mse_difference"]) <= 2 * versus["se"]:
            verdict = "within the packing scatter of each other"
        else:
            verdict = "the GNS route is better" if versus["mse_difference"] < 0 else "the DoE route is better"
        cost = "no more" if versus["gns_dem_runs"] <= versus["doe_dem_runs"] else "more"
        lines += [
            f"**GNS against {versus['doe_route']}** (the paper's claim): validated MSE of the GNS route minus "
            f"the DoE route's {versus['mse_difference']:+.3g} +- {format_se(versus['se'])} (paired, on "
            f"{versus.get('packings', result['validation_packings'])} packings), with "
            f"{versus['gns_dem_runs']} DEM runs{own_runs_text(versus)} against {versus['doe_dem_runs']} "
            f"({cost} DEM runs): {verdict}.",
            "",
        ]
    for route in result["routes"]:
        extra = route.get("extra") or {}
        if "r_squared" in extra:
            lines += [
                f"{route['route']}: {route['dem_runs']} DEM runs ({extra['failures']}); quadratic response "
                f"surface R^2 {extra['r_squared']:.3f}, lack of fit p = {extra['lack_of_fit_p']:.3g}; terms with "
                f"p < 0.05 (type-III ANOVA): {', '.join(extra['significant']) or 'none'}; the surface predicts "
                f"MSE {extra['predicted_mse']:.3g} at its optimum.",
                "",
            ]
        if "gns_objective" in extra:
            lines += [
                f"{route['route']}: the GNS's own objective at its optimum {extra['gns_objective']:.3g} (its "
                "error against the DEM shows in the gap to the validated MSE).",
                "",
            ]
        if "confirmation" in extra:
            confirmation = extra["confirmation"]
            scores = ", ".join(
                f"{value:.3g} -> " + ("failed" if c["mse"] is None else f"{c['mse']:.3g}")
                for value, c in zip(confirmation["surrogate_values"], confirmation["candidates"])
            )
            n_packings = len(confirmation["candidates"][0]["seeds"])
            packings = f"{n_packings} packing{'s' if n_packings > 1 else ''}"
            steps = confirmation.get("steps") or []
            corrected = ""
            if steps:
                moves = ", ".join(
                    f"{predicted:.3g} -> " + ("failed" if c["mse"] is None else f"{c['mse']:.3g}")
                    for predicted, c in zip(confirmation["predicted"], steps)
                )
                corrected = (
                    f" Then {len(steps)} correction step{'s' if len(steps) > 1 else ''} from the best of them, along "
                    f"the GNS's local slopes of L* with the DEM's own residual, on the same packings (foreseen -> "
                    f"DEM MSE: {moves})."
                )
            n_candidates = len(confirmation["candidates"])
            chosen = confirmation["chosen"]
            which = f"candidate {chosen + 1}" if chosen < n_candidates else f"step {chosen - n_candidates + 1}"
            lines += [
                f"{route['route']}: its {n_candidates} best distinct GNS points, run by the "
                f"DEM on {packings} of their own (GNS objective -> DEM MSE: {scores}).{corrected} The DEM's lowest, "
                f"{which}, was validated ({confirmation['dem_runs']} DEM runs, counted in the route's).",
                "",
            ]
    return lines


def dem_lines(result: dict, figure: str, section_path: StrPath) -> list[str]:
    """How the DEM ran and the answer was chosen, with the stage's figures and the model GNS's."""
    stated = "as the file states" if result.get("runout_stated") else "the config's: the file states none"
    lines = [
        f"DEM: {result['engine']} engine, size_scale {result['size_scale']:g} (parameters fitted at one scale are "
        f"effective values of that scale), runout read by {result['runout']['method']} ({stated}); the Bayesian "
        f"optimisation ran on packing seed {result['calibration_packing']}, the validation on "
        f"{result['validation_packings']} others. The answer is the route of this model with the lowest "
        f"validated MSE on {result.get('answer_packings', result['validation_packings'])} packings (so the "
        "choice, not each route's score, has seen the validation packings); the diagnosis fit's time is the "
        "diagnosis job's, its design runs' DEM time aside.",
        "",
        f"![calibrated model of {result['name']}]({figure})",
        "",
    ]
    for extra_figure, what in (
        ("bayesopt.png", "Bayesian optimisation"),
        ("doe_surface.png", "DoE response surface (face-centred CCD)"),
        ("doe_full_factorial_surface.png", "DoE response surface (3-level full factorial)"),
        ("inverse_paths.png", "GNS inverse design"),
    ):
        if (Path(result["figure"]).parent / extra_figure).exists():
            lines += [f"![{what} of {result['name']}]({Path(figure).with_name(extra_figure).as_posix()})", ""]
    # the model's own GNS (the GNS stage's rules on dataset calibrated_<name>): training and test split
    gns = Path(result["figure"]).parents[2] / "gns" / f"calibrated_{result['name']}"
    for gns_figure, what in (("train/loss_curve.png", "training"), ("evaluation/runout_curves.png", "test split")):
        if (gns / gns_figure).exists():
            link = Path(os.path.relpath(gns / gns_figure, Path(section_path).parent)).as_posix()
            lines += [f"![the {result['model']} model's GNS of {result['name']}, {what}]({link})", ""]
    return lines


def target_lines(result: dict, figure: str) -> list[str]:
    """The answer carried to the target size_scale: the coarse answer there, the correction's steps,
    the validation, the DEM runs and seconds at each scale, and the figure of the answer across
    grain sizes beside `figure` (calibrated.png's link); none where there is no target."""
    target = result.get("target")
    if not target:
        return []
    coarse, fine = f"size_scale {target['coarse_size_scale']:g}", f"size_scale {target['size_scale']:g}"
    correction, validation = target["correction"], target["validation"]
    start = correction["candidates"][0]
    steps = " -> ".join(f"{s['mse']:.3g}" if s["mse"] is not None else "failed" for s in correction["steps"])
    foreseen = ", ".join(f"{v:.3g}" for v in correction["predicted"] if v is not None)
    stepped = (
        f" {len(correction['steps'])} Gauss-Newton steps along the coarse DEM's slopes of L* (a star design of "
        f"{target['coarse_runs']} runs about it at {coarse}): MSE {steps} (foreseen {foreseen})."
        if correction["steps"]
        else " No step was taken."
    )
    parameters = ", ".join(f"{k} = {v:.3g}" for k, v in validation["parameters"].items())
    routes = result["routes"]
    route_runs = sum(r["dem_runs"] + len(r["seeds"]) for r in routes)
    route_seconds = sum(r["calibration_seconds"] + r["seconds"] for r in routes)
    rows = [
        (coarse, "every route's calibration and validation (not the GNS dataset, the diagnosis, the runoff)",
         route_runs, route_seconds),
        (coarse, "the slopes about the answer", target["coarse_runs"], target["coarse_seconds"]),
        (fine, "the correction and the validation", target["target_runs"], target["target_seconds"]),
    ]  # fmt: skip
    transfer = result.get("transfer")
    if transfer:
        rows.append((f"size_scale {transfer['size_scale']:g}", "the held-out transfer",
                     len(transfer["seeds"]), transfer["seconds"]))  # fmt: skip
    return [
        f"**At the target resolution ({fine}).** The answer above, found at {coarse}, scores MSE "
        f"{start['mse']:.3g} at {fine} (mean of {len(start['seeds'])} packings of its own).{stepped} The lowest, "
        f"**{parameters}**, validated at {fine}: MSE **{validation['mse']:.3g}** +- {format_se(validation['mse_se'])} "
        f"on {len(validation['seeds'])} packings (each alone: {format_span(validation['mse_each'])}). Use these "
        f"parameters at {fine}; its predictions below run there.",
        "",
        *plausibility_lines(validation["parameters"], result.get("plausible")),
        "| scale | DEM runs for | runs | s |",
        "| --- | --- | --- | --- |",
        *(f"| {scale} | {what} | {runs} | {seconds:.0f} |" for scale, what, runs, seconds in rows),
        "",
        f"![{result['name']}: the answer across grain sizes]({Path(figure).with_name('scales.png').as_posix()})",
        "",
    ]


def transfer_lines(result: dict, score: dict) -> list[str]:
    """The answer at finer grains against its score at the target or its own scale (none where not
    run): the parameters the two scales predict for the finer one (target_scale.predict_finer) where
    the answer was carried to a target, else the same parameters."""
    transfer = result["transfer"]
    if transfer is None:
        return []
    reference_mse, reference_scale = transfer_reference(result, score)
    target = result.get("target")
    finer = (target or {}).get("finer")
    fine = f"size_scale {transfer['size_scale']:g}"
    if finer:
        parameters = ", ".join(f"{k} {v:.3g}" for k, v in finer["parameters"].items())
        what = (
            f"The parameters for {fine}, predicted from the two scales with no run there: at the coarse answer "
            f"the model's own mean curve moved by MSE {finer['shift_mse']:.3g} from size_scale "
            f"{target['coarse_size_scale']:g} to {reference_scale:g} on the same packings (its runout grows as "
            f"its grains get finer); {finer['factor']:.2f} of that move per log grain size is expected from "
            f"{reference_scale:g} to {transfer['size_scale']:g}, and one Gauss-Newton step along the target's "
            f"slopes answers it: **{parameters}** (predicted MSE {finer['predicted_mse']:.3g}). Held out at {fine}"
        )
        holds, fails = "the prediction holds: use these parameters there.", "recalibrate at the scale you run."
    else:
        what = f"The same parameters at finer grains ({fine}), held out"
        holds, fails = (
            "the answer transfers.",
            "the parameters are effective values of their scale: recalibrate at the scale you run.",
        )
    verdict = holds if transfer_holds(transfer, reference_mse) else fails
    shift, least = None, None
    if not finer and target and target["validation"]["seeds"] == transfer["seeds"]:
        shift, least = resolution_shift(target["validation"]["mean"], transfer["mean"], reference_mse)
    moved = (
        ""
        if shift is None
        else f" On the same packing seeds the model's own mean curve moves by MSE {shift:.3g} from size_scale "
        f"{reference_scale:g} to {transfer['size_scale']:g}: its runout depends on grain size, so these "
        f"parameters, fitting at {reference_scale:g} to {reference_mse:.3g}, cannot score below {least:.3g} "
        f"at {transfer['size_scale']:g} (the RMS's triangle inequality)."
    )
    return [
        f"**Scale transfer.** {what} ({transfer['route']}): validated "
        f"MSE **{transfer['mse']:.3g}** (each packing {format_span(transfer['mse_each'])}) against "
        f"{reference_mse:.3g} at size_scale {reference_scale:g} on as many packings: {verdict}{moved}",
        "",
    ]


def prediction_lines(result: dict, figure: str) -> list[str]:
    """The answer's predictions across a against the scaling laws, and the contenders where the
    model was chosen by them."""
    p = result["prediction"]
    cells = [f"{v:.3g}" if v is not None else "failed" for v in p["final_runout"]]
    heights = [f"{v:.3g}" if v is not None else "failed" for v in p["height_over_L_i"]]
    check = check_scaling(p["aspect_ratios"], p["final_runout"], p["height_over_L_i"])
    fractions = [f"{v:.2f}" if v is not None else "failed" for v in check.runout_fraction()]
    lines = [
        f"**Prediction** (same material and L_i, size_scale {result['prediction_size_scale']:g}; one packing "
        "each): final runout at t/t* = "
        f"{PREDICTION_TSTAR:g} and deposit height by aspect ratio; the measured column (a = "
        f"{result['prediction_measured_a']:g}) reached L* = {result['measured_final_runout']:.3g} by its "
        "last time.",
        "",
        "| a | " + " | ".join(f"{a:g}" for a in p["aspect_ratios"]) + " |",
        "| --- |" + " --- |" * len(p["aspect_ratios"]),
        "| final L* | " + " | ".join(cells) + " |",
        f"| {QUASI_2D_SOURCE} | " + " | ".join(f"{v:.3g}" for v in check.runout_law) + " |",
        "| fraction of that law | " + " | ".join(fractions) + " |",
        f"| {DISC_2D_SOURCE} | " + " | ".join(f"{v:.3g}" for v in check.disc_law) + " |",
        "| H_f / L_i | " + " | ".join(heights) + " |",
        f"| {QUASI_2D_SOURCE} | " + " | ".join(f"{v:.3g}" for v in check.height_law) + " |",
        "",
        scaling_sentence(check),
        "",
        f"![predictions of {result['name']}]({Path(figure).with_name('prediction.png').as_posix()})",
        "",
    ]
    model_json = Path(result["figure"]).with_name("model.json")
    if model_json.exists() and json.loads(model_json.read_text()).get("scaling_check"):
        lines += contenders_lines(ContenderChoice.read(model_json.with_name("contenders.json")))
        link = Path(figure).with_name("contenders.png").as_posix()
        lines += [f"![the contenders of {result['name']}]({link})", ""]
    return lines


def runoff_lines(result: dict) -> list[str]:
    """The runoff in words and a table (none when the answer ran none), for the report section."""
    scored = result.get("runoff") or []
    if not scored:
        return []
    shared = scored[0]["shared_packings"]
    lines = [
        f"How the answer was chosen: the lowest of several {shared}-packing scores flatters itself, so the "
        f"{len(scored)} routes within 2 SE of the lowest (paired) ran on {result['answer_packings']} packings "
        f"(the {shared} shared first) and the lowest there is the answer:",
        "",
        f"| route | MSE on {shared} packings | MSE on {result['answer_packings']} packings +- SE |",
        "| --- | --- | --- |",
    ]
    first = {r["route"]: r["mse"] for r in result["routes"]}
    for r in scored:
        bold = "**" if r["route"] == result["answer"] else ""
        score = f"{r['mse']:.3g} +- {format_se(r['mse_se'])}"
        lines.append(f"| {bold}{r['route']}{bold} | {first[r['route']]:.3g} | {score} |")
    return [*lines, "", *tie_lines(result)]


def tie_lines(result: dict) -> list[str]:
    """The runoff's routes not told apart from the answer (paired difference within 2 SE on its
    packings), with the span of their parameters: which of them answers is a draw of the packings'
    chaos and of the machine's bits, not a finding. None where the runoff parted them."""
    scored = result.get("runoff") or []
    tied = [
        r
        for r in scored
        if r["route"] != result["answer"]
        and "versus_answer" in r
        and not_told_apart(r["versus_answer"]["mse_difference"], r["versus_answer"]["se"])
    ]
    if not tied:
        return []
    close = [r for r in scored if r["route"] == result["answer"]] + tied
    spans = ", ".join(
        f"{name} {min(r['parameters'][name] for r in close):.3g}-{max(r['parameters'][name] for r in close):.3g}"
        for name in close[0]["parameters"]
    )
    names = "; ".join(f"{r['route']} ({r['versus_answer']['mse_difference']:+.3g} +- "
                      f"{format_se(r['versus_answer']['se'])})" for r in tied)  # fmt: skip
    return [
        f"**The answer is not told apart from {len(tied)} other route{'s' if len(tied) > 1 else ''}** on these "
        f"{result['answer_packings']} packings (MSE difference from the answer, paired packing by packing, within "
        f"2 SE): {names}. Which of them answers is a draw of the packings' chaos and of the machine's bits (another "
        f"machine, seed or packing set may pick another); their parameters span {spans}: read that as the answer's "
        "uncertainty from the routes.",
        "",
    ]


def own_runs_text(versus: dict) -> str:
    """The GNS route's own DEM runs in words, for calibrated.json's gns_vs_doe ("" when its file
    does not say): the rest are the base GNS's, shared with the paper's route."""
    own, runs = versus.get("gns_own_dem_runs"), versus.get("gns_dem_runs")
    if own is None or own == runs:  # trained from scratch: every run is its own
        return ""
    return f" ({own} of its own dataset, the rest the base GNS's it starts from)"


def format_se(value: float | None) -> str:
    """A standard error as the report writes it ("n/a" where there is none)."""
    return f"{value:.2g}" if value is not None and math.isfinite(value) else "n/a"


def format_span(values: Sequence[float]) -> str:
    """The range of the finite values, "low-high" ("none ran" without any)."""
    finite = [v for v in values if math.isfinite(v)]
    return f"{min(finite):.3g}-{max(finite):.3g}" if finite else "none ran"


def run_section(json_paths: Sequence[StrPath], figure_paths: Sequence[StrPath], section_path: StrPath) -> None:
    """results/report/calibrated.md from every calibrated.json (workflow rule calibrated_section)."""
    results = []
    for path, figure in zip(json_paths, figure_paths, strict=True):
        data = CalibratedResult.from_json(path).to_dict()
        data["figure"] = str(figure)
        results.append(data)
    write_text(section_path, section_markdown(results, section_path))
