"""What a training writes of its progress beside its checkpoints: metrics.csv, one row per log or
validation step, and loss_curve.png drawn from the same rows.

A row (METRICS_COLUMNS) holds the step, the learning rate, the mean one-step and pushforward
training losses since the last row (normalised acceleration MSE, -), the last training batch's
graph (edges per node, particles per graph), the training speed (steps/s) and, on a validation
step, the validation's one-step loss (-), one-step position MSE (m^2), rollout runout MSE (of L*,
-) and failed rollouts; NaN where a row has no value.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from dem.atomic import atomic_path

METRICS_COLUMNS = (
    "step",
    "learning_rate",
    "train_loss",
    "train_pushforward_loss",
    "edges_per_node",
    "particles_per_graph",
    "steps_per_s",
    "valid_one_step_loss",
    "valid_position_mse",
    "valid_runout_mse",
    "valid_rollouts_failed",
)


def write_metrics(history: list[dict], out_dir: Path, best: dict | None = None, figure: bool = True) -> None:
    """out_dir/metrics.csv from the rows of `history` (METRICS_COLUMNS, NaN where a row lacks one);
    with figure, out_dir/loss_curve.png too, the best step marked (best: {"step": ...} or None)."""
    with atomic_path(out_dir / "metrics.csv") as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=METRICS_COLUMNS)
            writer.writeheader()
            writer.writerows({k: row.get(k, math.nan) for k in METRICS_COLUMNS} for row in history)
    if figure:
        plot_loss_curve(history, out_dir / "loss_curve.png", best)


def plot_loss_curve(history: list[dict], path: str | os.PathLike, best: dict | None = None) -> None:
    """Training loss and validation metrics against step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.plots import save_figure

    fig, (ax_loss, ax_runout) = plt.subplots(1, 2, figsize=(10, 3.8))
    column = lambda key: np.array([row.get(key, math.nan) for row in history], float)  # noqa: E731
    step = column("step")
    for key, style in (("train_loss", "-"), ("train_pushforward_loss", "-"), ("valid_one_step_loss", "o-")):
        ok = np.isfinite(column(key))
        if ok.any():
            ax_loss.plot(step[ok], column(key)[ok], style, label=key.replace("_", " "), ms=3)
    ax_loss.set(xlabel="step", ylabel="one-step loss (normalised acceleration MSE)", yscale="log")
    ax_loss.legend(fontsize=8)
    ok = np.isfinite(column("valid_runout_mse"))
    if ok.any():
        ax_runout.plot(step[ok], column("valid_runout_mse")[ok], "o-", ms=3, label="valid runout MSE")
        ax_runout.set(yscale="log")
    if best and best.get("step") is not None:
        ax_runout.axvline(best["step"], color="0.5", ls=":", label=f"best (step {best['step']})")
    ax_runout.set(xlabel="step", ylabel="runout MSE (L*) on the valid split")
    if ax_runout.get_legend_handles_labels()[0]:
        ax_runout.legend(fontsize=8)
    for ax in (ax_loss, ax_runout):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
