"""The runout-method study as a DAG stage (workflow/rules/runout.smk, rule runout_methods): every
method of dem.runout read off the DAG's own DEM runs (the GNS test cases, the DoE design centres),
with the GNS rollouts where a case has one; the statistics are dem/runout_study.py's. Writes
results/runout/methods.json, its figure and the report section (results/report/runout.md).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from dem.atomic import StrPath, write_json, write_text
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from dem.runout_study import PACKINGS, PERTURBATION, RERUNS, compare_methods, markdown_table, plot_methods
from dem.trajectory import read_trajectory

log = logging.getLogger(__name__)


def run_runout_methods(
    labels: Sequence[str],
    trajectory_paths: Sequence[StrPath],
    rollout_paths: Mapping[str, StrPath],
    out_json: StrPath,
    out_figure: StrPath,
    out_section: StrPath,
    runout: RunoutMethod | dict | str,
    n_packings: int = PACKINGS,
    n_reruns: int = RERUNS,
) -> dict:
    """The runout-method study on the DAG's own runs: methods.json, the figure and the report section.

    labels [k] / trajectory_paths [k]: the cases (GNS test cases, DoE centres); rollout_paths
    {label: GNS rollout}; runout: the configured method (the section says which one it is).
    """
    runout = RunoutMethod.from_config(runout)
    cases = {label: read_trajectory(path) for label, path in zip(labels, trajectory_paths)}
    rollouts = {label: read_trajectory(path) for label, path in rollout_paths.items()}
    progress = progress_logger(f"runout methods, {len(cases) * (n_packings + n_reruns)} DEM runs", log)
    study, curves = compare_methods(
        cases, n_packings=n_packings, n_reruns=n_reruns, rollouts=rollouts, progress=progress
    )
    study["configured"] = runout.to_config()
    write_json(out_json, study)
    plot_methods(curves, out_figure)
    figure = Path(os.path.relpath(out_figure, Path(out_section).parent)).as_posix()
    text = "\n".join(
        [
            f"Every stage reads L* as the **{runout.label}** (config key `runout`, method `{runout.method}`). "
            "A lab reads the runout off images of the dense front, and a front it has read never moves back; "
            "the table shows what each method does with the same DEM runs: the scatter of L* between "
            f"{n_packings} packings of each case, per phase, the largest backward jump of L* between frames, "
            f"and the chaos floor ({n_reruns} reruns from the case's own packing, every grain moved by "
            f"{PERTURBATION:g} diameters): a rerun scored against the run (rerun MSE) and the best any "
            "deterministic surrogate can do (ideal MSE). GNS columns: its test rollouts, where the case has one. "
            f"Means over {len(cases)} cases ({', '.join(cases)}); per case in `{Path(out_json).as_posix()}`.",
            "",
            markdown_table(study),
            "",
            f"![runout of every packing read by each method]({figure})",
            "",
        ]
    )
    write_text(out_section, text)
    return study
