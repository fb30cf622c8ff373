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
from dem.scale_ladder import READ_AT, plot_ladder, read_run, summarise
from dem.trajectory import read_attrs, read_trajectory
from pipeline.scale_ladder_section import section_text

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
