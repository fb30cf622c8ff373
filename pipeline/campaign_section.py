"""The report's section on the campaigns (workflow rule campaign_section): per campaign, the answer,
every route side by side (validated MSE per column, each column predicted from the others against
its packing scatter, the cost per added column), and the figure of every column."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

from calibration.campaign import SCATTER_LEVEL
from dem.atomic import StrPath, write_text
from pipeline.campaign import CampaignResult


def section_markdown(results: Sequence[CampaignResult], figures: Sequence[StrPath], section_path: StrPath) -> str:
    """The section's markdown: one part per campaign, figures linked relative to section_path."""
    lines = [
        "A campaign is a `measured` entry of several columns of one material, calibrated as one parameter set: "
        "each route runs every parameter point on every column, and its objective is the columns' weighted mean "
        "runout MSE. Each column is then predicted from the others: the route calibrated without it (from its "
        "own runs) and run on the held-out column. A prediction is *within the scatter* when its MSE stays "
        f"under {SCATTER_LEVEL:g} x (the packing variance of one run x (1 + 1/R) + the data's stated variance): "
        "the 95% level of the miss the true parameters themselves would show, the measured column being one "
        "packing and the prediction the mean of R.",
        "",
    ]
    for result, figure in zip(results, figures, strict=True):
        lines += campaign_lines(result, Path(os.path.relpath(figure, Path(section_path).parent)).as_posix())
    return "\n".join(lines) + "\n"


def campaign_lines(result: CampaignResult, figure: str) -> list[str]:
    """One campaign: its answer, the routes' table, the held-out table and the figure."""
    answer = result.answer_route
    columns = ", ".join(
        f"{c} (a = {a:g}, L_i = {L * 1e3:g} mm)" for c, a, L in zip(result.columns, result.aspect_ratios, result.L_i)
    )
    parameters = ", ".join(f"{k} = {v:.4g}" for k, v in answer.optimum.parameters.items())
    lines = [
        f"## {result.name}",
        "",
        f"Columns: {columns}; {result.weighting}.",
        "",
        f"**The answer:** the {answer.model} model by {answer.route}, the route that predicts held-out columns "
        f"best (campaign MSE of its held-out predictions {answer.held_out_mse:.3g}): {parameters}; validated "
        f"campaign MSE {format_mse(answer.mse, answer.mse_se)} on {len(answer.validations[0].seeds)} packings per "
        "column.",
        "",
        "| route | "
        + " | ".join(f"MSE {c}" for c in result.columns)
        + " | campaign MSE | held out | DEM runs | per added column |",
        "| --- | " + " | ".join("---" for _ in result.columns) + " | --- | --- | --- | --- |",
    ]
    for route in result.routes:
        per_column = " | ".join(format_mse(v.mse, v.mse_se) for v in route.validations)
        cost = f"{route.runs_per_column:.0f} runs, {route.seconds_per_column:.0f} s"
        lines.append(
            f"| {route.route} | {per_column} | {format_mse(route.mse, route.mse_se)} | {route.held_out_mse:.3g} | "
            f"{route.dem_runs} | {cost} |"
        )
    lines += cost_lines(result)
    lines += ["", "Each column predicted from the others (its MSE against the bound of the packing scatter):", ""]
    lines += held_out_table(result)
    lines += ["", f"![{result.name}: every column, and each from the others]({figure})", ""]
    return lines


def cost_lines(result: CampaignResult) -> list[str]:
    """What each route's calibration spent, and how an added column's cost is counted where it is not
    an equal share of it (the GNS route: its dataset and training beside its search)."""
    lines = [""]
    for route in result.routes:
        spent = f"{route.dem_runs} DEM runs, {route.seconds:.0f} s"
        if route.surrogate_seconds:
            spent += (
                f" ({route.surrogate_seconds:.0f} s of them its dataset's runs and its training, "
                f"{route.seconds - route.surrogate_seconds:.0f} s its search)"
            )
        why = route.added_column_why or "an equal share of its calibration (every point runs on every column)"
        lines.append(f"- {route.route}: calibration {spent}; an added column: {why}.")
    return lines


def held_out_table(result: CampaignResult) -> list[str]:
    """The leave-one-column-out table: per route, per column, MSE / bound and the parameters."""
    lines = [
        "| route | held out | predicted MSE | scatter bound | within | parameters from the others |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for route in result.routes:
        for held in route.held_out:
            parameters = ", ".join(f"{k} {v:.3g}" for k, v in held.optimum.parameters.items())
            lines.append(
                f"| {route.route} | {held.column} | {format_mse(held.validation.mse, held.validation.mse_se)} | "
                f"{held.scatter_bound:.3g} | {'yes' if held.within_scatter else 'no'} | {parameters} |"
            )
    return lines


def format_mse(value: float, se: float | None) -> str:
    if not math.isfinite(value):
        return "n/a (no run ran)"
    return f"{value:.3g}" + ("" if se is None else f" +- {se:.2g}")


def run_section(json_paths: Sequence[StrPath], figure_paths: Sequence[StrPath], section_path: StrPath) -> None:
    """results/report/campaign.md from every campaign.json (workflow rule campaign_section)."""
    results = [CampaignResult.read(path) for path in json_paths]
    write_text(section_path, section_markdown(results, figure_paths, section_path))
