"""The report's first page: the answer for one measured column in a few lines (which model, its
parameters with 95% intervals, how well DEM runs at them reproduce the measurement, what each
calibration route cost) above the headline figure, as a small self-contained HTML fragment,
results/report/answer_<name>.html (workflow rule calibrated_section, beside the Markdown section).

Snakemake's HTML report shows it under "1. The answer" and on its first page
(workflow/report/workflow.rst includes it), so it is a fragment styled inline: no <html>, no
<style> that could restyle the page around it, ASCII only (other characters as entities). The
numbers are calibrated.json's, formatted as pipeline/calibrated_section.py's Markdown section formats them.
"""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Sequence
from pathlib import Path

from calibration.calibrated_result import CalibratedResult
from dem.atomic import StrPath, write_text
from pipeline.calibrated_section import answer_score, format_se, format_span, transfer_holds, transfer_reference

CELL = "padding: 2px 10px 2px 0; text-align: left; vertical-align: top"
FIRST_SENTENCE = re.compile(r"(?<=[.:])\s+(?=[A-Z])")


def answer_html(result: dict, figure: StrPath | None = None) -> str:
    """The answer page of one measured column from its calibrated.json `result`, with the PNG at
    `figure` (calibrated.png) embedded under it when given."""
    score = answer_score(result)
    answer = score["route"]
    e = html.escape
    why = FIRST_SENTENCE.split(result["why"].strip(), maxsplit=1)[0]
    chosen = (
        ""
        if score["shared"] is None
        else f" It was chosen on these {score['n_ran']} among the routes within 2 SE of the lowest score on the "
        f"{score['shared']} packings every route ran (there {score['shared_mse']:.3g}): the lowest of several "
        "few-packing scores flatters itself."
    )
    parts = [
        '<div style="font-family: sans-serif; font-size: 14px; line-height: 1.45; max-width: 60em">',
        f'<h3 style="margin: 0.3em 0">{e(result["name"])}: the {e(result["model"])} model</h3>',
        f"<p><b>Which model.</b> {e(why)}</p>",
        f"<p><b>Which parameters</b> (route: {e(answer['route'])}):</p>",
        _parameter_table(result, answer),
        f"<p><b>How well.</b> DEM runs at these parameters reproduce the measured runout "
        f"({e(result['column'])}) with MSE <b>{score['mse']:.3g}</b> &plusmn; {format_se(score['mse_se'])} "
        f"(jackknife SE) on the mean L* of {score['n_ran']} packings the calibration never saw; each packing "
        f"alone {format_span(score['mse_each'])}.{chosen}{_transfer(result, score)}</p>",
        f"<p><b>What it cost.</b> This route: {_runs(answer)} DEM runs and "
        f"{_duration(answer['calibration_seconds'])} to calibrate ({result['engine']} engine, size_scale "
        f"{result['size_scale']:g}). Every route, validated on the same packings:</p>",
        _route_table(result, answer),
    ]
    if figure is not None:
        data = base64.b64encode(Path(figure).read_bytes()).decode("ascii")
        parts.append(
            f'<img src="data:image/png;base64,{data}" alt="validated runout curves of {e(result["name"])}" '
            'style="max-width: 100%; margin-top: 0.5em">'
        )
    parts.append("</div>")
    return "\n".join(parts) + "\n"


def _parameter_table(result: dict, answer: dict) -> str:
    """Parameter, answer value, and the 95% intervals there are: the diagnosis' Laplace posterior
    of the model (about its own fit) and the GNS inverse design's (about the GNS optimum)."""
    sources = [
        (key, label)
        for key, label in (
            ("intervals", "95% interval (diagnosis fit)"),
            ("gns_intervals", "95% interval (GNS inverse design)"),
        )
        if result.get(key)
    ]
    head = "".join(f'<th style="{CELL}">{label}</th>' for label in ["parameter", "value", *(s for _, s in sources)])
    rows = []
    for name, value in answer["parameters"].items():
        cells = [name, f"{value:.3g}"]
        for key, _ in sources:
            interval = next((p for p in result[key] if p["name"] == name), None)
            cells.append(_interval(interval))
        rows.append("<tr>" + "".join(f'<td style="{CELL}">{html.escape(c)}</td>' for c in cells) + "</tr>")
    return f'<table style="border-collapse: collapse"><tr>{head}</tr>{"".join(rows)}</table>'


def _route_table(result: dict, answer: dict) -> str:
    head = "".join(
        f'<th style="{CELL}">{label}</th>'
        for label in ("route", "DEM runs", "time to calibrate", "validated MSE &plusmn; SE")
    )
    rows = []
    for route in result["routes"]:
        cells = [
            html.escape(route["route"]),
            html.escape(str(_runs(route))),
            _duration(route["calibration_seconds"]),
            f"{route['mse']:.3g} &plusmn; {format_se(route.get('mse_se'))}",
        ]
        weight = "font-weight: bold; " if route is answer else ""
        rows.append("<tr>" + "".join(f'<td style="{weight}{CELL}">{c}</td>' for c in cells) + "</tr>")
    return f'<table style="border-collapse: collapse; font-size: 13px"><tr>{head}</tr>{"".join(rows)}</table>'


def _interval(p: dict | None) -> str:
    if p is None:
        return ""
    return f"[{p['low']:.3g}, {p['high']:.3g}]" + ("" if p["identifiable"] else " not identifiable")


def _transfer(result: dict, score: dict) -> str:
    target, transfer = result.get("target"), result.get("transfer")
    text = ""
    if target:
        v = target["validation"]
        parameters = ", ".join(f"{k} {x:.3g}" for k, x in v["parameters"].items())
        text = (
            f" At the target size_scale {target['size_scale']:g}, corrected by {target['target_runs']} DEM runs "
            f"there: <b>{parameters}</b>, validated MSE {v['mse']:.3g} &plusmn; {format_se(v['mse_se'])}."
        )
    if not transfer or not math.isfinite(transfer["mse"]):
        return text
    reference_mse, reference_scale = transfer_reference(result, score)
    holds = transfer_holds(transfer, reference_mse)
    at = f" (size_scale {transfer['size_scale']:g})" if "size_scale" in transfer else ""
    finer = (target or {}).get("finer")
    if finer:
        parameters = ", ".join(f"{k} {x:.3g}" for k, x in finer["parameters"].items())
        what = f"the parameters the two scales predict for it, <b>{parameters}</b>,"
        verdict = ": use them there." if holds else ": recalibrate at the scale you run."
    else:
        what = "the same parameters"
        verdict = ": the answer transfers." if holds else ": recalibrate at the scale you run."
    return text + (
        f" Finer still{at}, held out, {what} score MSE {transfer['mse']:.3g} (at size_scale "
        f"{reference_scale:g}: {reference_mse:.3g} on as many packings){verdict}"
    )


def _runs(route: dict) -> int | str:
    return route["dem_runs"] or "those of the GNS dataset"


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "n/a"
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


def run_answers(json_paths: Sequence[StrPath], figure_paths: Sequence[StrPath], out_paths: Sequence[StrPath]) -> None:
    """results/report/answer_<name>.html of every measured column from its calibrated.json and
    calibrated.png (workflow rule calibrated_section)."""
    for path, figure, out in zip(json_paths, figure_paths, out_paths, strict=True):
        text = answer_html(CalibratedResult.from_json(path).to_dict(), figure)
        write_text(out, text.encode("ascii", "xmlcharrefreplace").decode("ascii"))
