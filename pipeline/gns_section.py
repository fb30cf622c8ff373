"""The GNS stage's report section (results/report/gns.md): the test-split accuracy of every trained
model, its training and its rollouts against the DEM (pipeline/gns.py writes the numbers it reads)."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dem.atomic import StrPath, write_text
from dem.runout import RunoutMethod


def section(
    datasets: Sequence[str],
    summaries: Sequence,
    loss_curves: Sequence,
    training_metrics: Sequence,
    fragment_path: StrPath,
) -> str:
    """Write the report section at `fragment_path` (report_section's Markdown); returns the text."""
    text = report_section(datasets, summaries, loss_curves, training_metrics, fragment_path)
    write_text(fragment_path, text)
    return text


def report_section(
    datasets: Sequence[str],
    summaries: Sequence[StrPath],
    loss_curves: Sequence[StrPath],
    training_metrics: Sequence[StrPath],
    fragment_path: StrPath,
) -> str:
    """Markdown for results/report/gns.md, one block per dataset; links relative to `fragment_path`.

    summaries: evaluation summary.json paths; loss_curves / training_metrics: the training's
    loss_curve.png / metrics.csv paths, all in `datasets` order.
    """
    import pandas as pd

    where = Path(fragment_path).parent
    rel = lambda p: os.path.relpath(p, where)  # noqa: E731
    lines = [
        "GNS rollouts of each test case from its first C frames to its last frame, against the DEM. "
        "Runout MSE: mean over frames of (L*_GNS - L*_DEM)^2 (the paper reports 0.172 for quartz and "
        "0.167 for copper; the target here is at most 0.05). A collapse is chaotic: the DEM rerun from the "
        "same packing with every grain moved by 0.001 diameters differs from its first run too, and no "
        "surrogate can score below that scatter (`python benchmarks/gns_floor.py` measures it for a "
        "dataset). Position MSE in mean grain diameters squared.",
        "",
        f"Runout read as the {RunoutMethod.from_config(json.loads(Path(summaries[0]).read_text()).get('runout')).label}"
        " (config key `runout`)."
        if summaries
        else "",
        "",
        "| dataset | steps | training (min) | best step | valid runout MSE | test cases | failed | "
        "test runout MSE | position MSE (d^2) | rollout (s/case) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, summary_path, metrics_path in zip(datasets, summaries, training_metrics):
        summary = json.loads(Path(summary_path).read_text())
        metrics = pd.read_csv(metrics_path)
        validated = metrics[np.isfinite(metrics["valid_runout_mse"])]
        best = validated.loc[validated["valid_runout_mse"].idxmin()] if len(validated) else None
        steps = np.diff(np.concatenate([[0], metrics["step"].to_numpy()]))
        minutes = float(np.nansum(steps / metrics["steps_per_s"].to_numpy())) / 60
        lines.append(
            f"| {name} | {int(metrics['step'].max())} | {minutes:.3g} | "
            f"{int(best['step']) if best is not None else '-'} | "
            f"{best['valid_runout_mse'] if best is not None else float('nan'):.4g} | {summary['n_cases']} | "
            f"{summary['n_failed']} | **{summary['runout_mse']:.4g}** | {summary['position_mse_d2']:.3g} | "
            f"{summary['gns_rollout_s_mean']:.3g} |"
        )
    for name, summary_path, curve in zip(datasets, summaries, loss_curves):
        summary = json.loads(Path(summary_path).read_text())
        eval_dir = Path(summary_path).parent
        lines += [
            "",
            f"### {name}",
            "",
            "| case | mu | e | a | L_i (mm) | grains | runout MSE | final L* DEM | "
            "final L* GNS | position MSE (d^2) | GNS rollout (s) | DEM run (s) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in summary["cases"]:
            problem = " (rollout failed, see metrics.csv)" if not r["valid"] else ""
            lines.append(
                f"| {r['case']}{problem} | {r['friction']:.3g} | {r['restitution']:.3g} | {r['aspect_ratio']:.3g} | "
                f"{r['L_i'] * 1e3:.3g} | {r['n_particles']} | {r['runout_mse']:.4g} | {r['final_runout_dem']:.3g} | "
                f"{r['final_runout_gns']:.3g} | {r['position_mse_d2']:.3g} | {r['gns_rollout_s']:.3g} | "
                f"{r['dem_run_s']:.3g} |"
            )
        lines += [
            "",
            f"![{name}: training loss and validation runout MSE]({rel(curve)})",
            "",
            f"![{name}: runout curves, DEM solid, GNS dashed]({rel(eval_dir / 'runout_curves.png')})",
            "",
        ]
        for r in summary["cases"]:
            snapshot = rel(eval_dir / "snapshots" / (r["case"] + ".png"))
            lines += [f"![{name} {r['case']}: DEM (left) and GNS (right)]({snapshot})", ""]
    return "\n".join(lines)
