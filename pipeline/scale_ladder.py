"""The scale ladder as a DAG stage (workflow/rules/scale_ladder.smk, rule scale_ladder): one column
and parameter set run at several size_scale through the DEM stage's rules (case-table dataset
scale_ladder), read here by the configured runout method (dem/scale_ladder.py does the reading,
the summary and the figure). Writes results/scale_ladder/summary.json, its figure and the report
section (results/report/scale_ladder.md).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

from dem.atomic import StrPath, write_json, write_text
from dem.plots import case_title
from dem.runout import RunoutMethod
from dem.scale_ladder import READ_AT, plot_ladder, read_run, scale_label, summarise
from dem.trajectory import read_attrs, read_trajectory

log = logging.getLogger(__name__)


def run_scale_ladder(
    trajectory_paths: Sequence[StrPath],
    packing_paths: Sequence[StrPath],
    out_json: StrPath,
    out_figure: StrPath,
    out_section: StrPath,
    runout: RunoutMethod | dict | str,
) -> dict:
    """Read every run of the ladder (trajectory_paths [k] and the settled packing it started from,
    packing_paths [k]: the settle's cost) by `runout`, the configured method; write summary.json
    ({"case", "runout", "read_at", "by_size_scale": dem.scale_ladder.summarise}), the figure and
    the report section. Returns the summary."""
    runout = RunoutMethod.from_config(runout)
    if len(trajectory_paths) != len(packing_paths):
        raise ValueError(f"{len(trajectory_paths)} trajectories but {len(packing_paths)} packings")
    runs, attrs = [], {}
    for trajectory_path, packing_path in zip(trajectory_paths, packing_paths):
        trajectory = read_trajectory(trajectory_path)
        attrs = trajectory.attrs
        runs.append(read_run(trajectory, runout, read_attrs(packing_path).get("wall_time_s")))
        log.info("read %s: size_scale %g, %d grains", trajectory_path, runs[-1].size_scale, runs[-1].n_particles)
    by_scale = summarise(runs)
    summary = {
        "case": {key: attrs[key] for key in ("material", "L_i", "aspect_ratio", "friction", "restitution")},
        "runout": runout.to_config(),
        "read_at": list(READ_AT),
        "by_size_scale": by_scale,
    }
    write_json(out_json, summary)
    title = case_title(attrs)
    plot_ladder(by_scale, runs, out_figure, title)
    figure = Path(os.path.relpath(out_figure, Path(out_section).parent)).as_posix()
    write_text(out_section, section_text(summary, title, runout, Path(out_json).as_posix(), figure))
    return summary


def _value(stats: dict, digits: int) -> str:
    """`mean +- std` of a scatter() entry; `mean` alone for one packing; `n/a` when unknown."""
    if stats["mean"] is None:
        return "n/a"
    if stats["std"] is None:
        return f"{stats['mean']:.{digits}f}"
    return f"{stats['mean']:.{digits}f} +- {stats['std']:.{digits}f}"


def section_text(summary: dict, title: str, runout: RunoutMethod, json_path: str, figure: str) -> str:
    """The report section: what ran, the table per size_scale, the trend in one sentence, the figure."""
    by_scale = summary["by_size_scale"]
    read_at = sorted({x for entry in by_scale.values() for x in entry["runout_at"]}, key=float)
    counts = sorted({len(entry["seeds"]) for entry in by_scale.values()})
    packings = (
        "1 packing each" if counts == [1] else f"{' or '.join(map(str, counts))} packings each, their scatter after +-"
    )
    header = ["size_scale", "grains (across)"] + [f"L* at t/t* = {x}" for x in read_at]
    header += ["final L*", "final height / H_i", "s per run (settle + collapse)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for label, entry in by_scale.items():
        at = [_value(entry["runout_at"][x], 2) if x in entry["runout_at"] else "" for x in read_at]
        cost = " + ".join(
            "n/a" if s["mean"] is None else f"{s['mean']:.3g}" for s in (entry["settle_s"], entry["collapse_s"])
        )
        cells = [label, f"{entry['n_particles']:,} ({entry['grains_across']:.1f})", *at]
        cells += [_value(entry["final_runout"], 2), _value(entry["final_height_over_H_i"], 3), cost]
        lines.append("| " + " | ".join(cells) + " |")
    coarse, fine = next(iter(by_scale.values())), list(by_scale.values())[-1]
    if len(by_scale) > 1:
        change = fine["final_runout"]["mean"] / coarse["final_runout"]["mean"] - 1
        trend = (
            f"From size_scale {scale_label(coarse['size_scale'])} to {scale_label(fine['size_scale'])} the final "
            f"L* goes from {coarse['final_runout']['mean']:.2f} to {fine['final_runout']['mean']:.2f} "
            f"({change:+.0%}) and the final deposit height from {coarse['final_height_over_H_i']['mean']:.3f} "
            f"to {fine['final_height_over_H_i']['mean']:.3f} H_i. "
        )
    else:
        trend = "One size_scale only: no trend to read. "
    text = [
        f"How the runout depends on grain size: {title}, run at size_scale "
        f"{', '.join(by_scale)} ({packings}), "
        f"L* read as the **{runout.label}**, the final values at the last frame "
        f"(t/t* = {coarse['final_t_over_tstar']:.3g}). "
        + trend
        + "Where the values part by more than their packing scatter, parameters calibrated at one size_scale "
        "are effective values of that scale. Seconds per run: the mean settle and collapse alone (no job "
        f"overhead). Per packing in `{json_path}`.",
        "",
        "\n".join(lines),
        "",
        f"![L*(t/t*) per size_scale and the final deposit against size_scale]({figure})",
        "",
    ]
    return "\n".join(text)
