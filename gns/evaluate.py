"""Accuracy of GNS rollouts against the DEM on held-out cases, with figures like the paper's Figs. 6-8.

Runout MSE (the paper's metric, 0.172 quartz / 0.167 copper): mean over every frame of
(L*_GNS - L*_DEM)^2, L* read by the configured runout method (dem.runout) for both. Position MSE: mean squared
distance between GNS and DEM grain centres over the predicted frames, in m^2 and in mean grain
diameters^2 (comparable across coarse-graining). The summary keeps each valid case's two runout
curves, so a consumer can read the GNS's error at its own t/t* points (runout_error_at).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from dem.atomic import atomic_path, write_text
from dem.runout import RunoutError, RunoutMethod, runout_curve
from dem.trajectory import Trajectory, read_trajectory

SNAPSHOT_TSTAR = (0.0, 1.0, 1.5, 2.0, 4.0)


def rollout_runout_mse(
    dem: Trajectory,
    gns: Trajectory,
    runout: RunoutMethod,
    curves: tuple[np.ndarray, np.ndarray] | None = None,
) -> float:
    """Mean over frames of (L*_gns - L*_dem)^2, both read by `runout`; both must cover the same frames.
    curves: (L*_dem [T], L*_gns [T]) when the caller has already read them (not read again)."""
    if gns.n_frames != dem.n_frames:
        raise ValueError(
            f"GNS rollout has {gns.n_frames} frames, DEM {dem.n_frames}: a rollout that stopped "
            f"early ({gns.attrs.get('rollout_problem', '')}) has no full runout curve"
        )
    runout_dem, runout_gns = curves or (runout_curve(dem, runout)[1], runout_curve(gns, runout)[1])
    return float(np.mean((runout_gns - runout_dem) ** 2))


def position_mse(dem: Trajectory, gns: Trajectory, n_input_frames: int) -> float:
    """Mean squared centre distance (m^2) over the predicted frames n_input_frames.. of the rollout."""
    frames = slice(n_input_frames, gns.n_frames)
    difference = gns.positions[frames].astype(np.float64) - dem.positions[frames].astype(np.float64)
    return float(np.mean(np.sum(difference**2, axis=-1)))


def evaluate_rollouts(
    pairs: Iterable[tuple[str | os.PathLike, str | os.PathLike]],
    out_dir: str | os.PathLike,
    runout: RunoutMethod | dict | str,
    n_input_frames: int | None = None,
) -> dict:
    """Score GNS rollouts against their DEM trajectories and draw the figures.

    pairs: [(dem trajectory path, gns rollout path)]. Writes in out_dir: metrics.csv (one row per
    case), summary.json, runout_curves.png (Fig. 7 style) and snapshots/<case>.png (Figs. 6/8
    style: DEM and GNS side by side at t/t* = 0, 1, 1.5, 2, 4). runout: the runout method every L*
    is read by (recorded in the summary). Returns the summary.
    """
    runout = RunoutMethod.from_config(runout)
    out_dir = Path(out_dir)
    rows, curves, kept_curves = [], [], []
    for dem_path, gns_path in pairs:
        dem, gns = read_trajectory(dem_path), read_trajectory(gns_path)
        c = n_input_frames or int(gns.n_frames - gns.attrs.get("rollout_steps", gns.n_frames - 1))
        valid = bool(gns.attrs.get("rollout_valid", 1))
        diameter = 2 * float(np.mean(dem.radius))
        name = Path(dem_path).stem
        row = {
            "case": name,
            "dem": str(dem_path),
            "gns": str(gns_path),
            "valid": int(valid),
            "problem": gns.attrs.get("rollout_problem", ""),
            "friction": float(dem.attrs["friction"]),
            "restitution": float(dem.attrs["restitution"]),
            "aspect_ratio": float(dem.attrs["aspect_ratio"]),
            "L_i": float(dem.attrs["L_i"]),
            "n_particles": dem.n_particles,
            "frames": dem.n_frames,
            "gns_rollout_s": float(gns.attrs.get("wall_time_s", math.nan)),
            "dem_run_s": float(dem.attrs.get("wall_time_s", math.nan)),
        }
        position = position_mse(dem, gns, c)
        row.update(position_mse_m2=position, position_mse_d2=position / diameter**2)
        t_dem, runout_dem = runout_curve(dem, runout)
        try:
            t_gns, runout_gns = runout_curve(gns, runout)
        except RunoutError as exc:  # a rollout spread too thin for the rule: failed, said why
            valid = False
            row.update(valid=0, problem=f"{row['problem']}; no runout: {exc}".lstrip("; "))
            t_gns, runout_gns = t_dem[:1], np.full(1, math.nan)
        row.update(
            runout_mse=rollout_runout_mse(dem, gns, runout, curves=(runout_dem, runout_gns)) if valid else math.nan,
            final_runout_dem=float(runout_dem[-1]),
            final_runout_gns=float(runout_gns[-1]) if valid else math.nan,
        )
        rows.append(row)
        curves.append((name, dem.attrs, t_dem, runout_dem, t_gns, runout_gns))
        if valid:
            kept_curves.append(
                {"case": name, "t_over_tstar": t_dem.tolist(), "dem": runout_dem.tolist(), "gns": runout_gns.tolist()}
            )
        plot_side_by_side(dem, gns, out_dir / "snapshots" / f"{name}.png")
    plot_runout_curves(curves, out_dir / "runout_curves.png", runout.label)
    ok = [r for r in rows if r["valid"]]
    summary = {
        "runout": runout.to_config(),
        "n_cases": len(rows),
        "n_failed": len(rows) - len(ok),
        "runout_mse": float(np.mean([r["runout_mse"] for r in ok])) if ok else math.nan,
        "runout_mse_max": float(np.max([r["runout_mse"] for r in ok])) if ok else math.nan,
        "position_mse_m2": float(np.mean([r["position_mse_m2"] for r in rows])) if rows else math.nan,
        "position_mse_d2": float(np.mean([r["position_mse_d2"] for r in rows])) if rows else math.nan,
        "gns_rollout_s_mean": float(np.mean([r["gns_rollout_s"] for r in rows])) if rows else math.nan,
        "cases": rows,
        "runout_curves": kept_curves,  # per valid case: t/t* [T], L*_DEM [T], L*_GNS [T]
    }
    _write_csv(rows, out_dir / "metrics.csv")
    write_text(out_dir / "summary.json", json.dumps(summary, indent=1, default=float) + "\n")
    return summary


def runout_error_at(summary: dict, t_over_tstar: Sequence[float] | np.ndarray) -> np.ndarray | None:
    """RMS over the summary's valid cases of L*_GNS - L*_DEM [K] at t/t* points [K], each case's
    curves interpolated there; None when no case was valid (every rollout failed: no error measured).
    Per point, not over the whole curve: the error grows as the collapse spreads (0.01 at t/t* = 0.5,
    0.7 at 3.5 for the calibrated quartz model's GNS), and one number for every point would swamp
    the early points' information."""
    if "runout_curves" not in summary:
        raise ValueError(
            "the GNS evaluation summary holds no runout curves (written before they were kept): rerun the GNS "
            "evaluation"
        )
    curves = summary["runout_curves"]
    if not curves:
        return None
    t_query = np.asarray(t_over_tstar, float)
    errors = [
        np.interp(t_query, c["t_over_tstar"], c["gns"]) - np.interp(t_query, c["t_over_tstar"], c["dem"])
        for c in curves
    ]
    return np.sqrt(np.mean(np.square(errors), axis=0))


def _write_csv(rows, path):
    import csv

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as f:
            if rows:
                writer = csv.DictWriter(f, fieldnames=list(rows[0]))
                writer.writeheader()
                writer.writerows(rows)


def plot_side_by_side(
    dem: Trajectory, gns: Trajectory, path: str | os.PathLike, snapshots: Sequence[float] = SNAPSHOT_TSTAR
) -> None:
    """DEM (left) and GNS (right) snapshots at t/t* in `snapshots` (paper Figs. 6 and 8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.plots import case_title, draw_grains, save_figure

    t = dem.t_over_tstar
    shown = [s for s in snapshots if s <= t[-1] + 1e-9]
    extent = max(float(dem.positions[:, :, 0].max()), float(gns.positions[:, :, 0].max())) * 1.1
    height = float(dem.positions[0, :, 1].max()) * 1.15
    fig, axes = plt.subplots(
        len(shown), 2, figsize=(10, 1.1 + len(shown) * max(1.0, 5 * height / extent)), squeeze=False
    )
    for row, s in enumerate(shown):
        k = int(np.argmin(np.abs(t - s)))
        for col, (traj, colour) in enumerate(((dem, "tab:orange"), (gns, "tab:blue"))):
            ax = axes[row, col]
            if k < traj.n_frames:
                draw_grains(ax, traj.positions[k], traj.radius, color=colour)
            else:
                ax.text(0.5, 0.5, "rollout stopped", transform=ax.transAxes, ha="center")
            ax.axvline(float(dem.attrs["L_i"]), color="0.6", lw=0.8, ls=":")
            ax.set(xlim=(0, extent), ylim=(0, height), aspect="equal")
            ax.set_title(f"{'DEM' if col == 0 else 'GNS'}  t/t* = {t[k]:.2f}", fontsize=8, loc="left")
            ax.tick_params(labelsize=6)
    fig.suptitle(case_title(dem.attrs, length=False), fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def plot_runout_curves(curves: Sequence[tuple], path: str | os.PathLike, runout_label: str = "") -> None:
    """L*(t/t*) of DEM (solid) and GNS (dashed) for every case (paper Fig. 7); L* and t/t* are
    dimensionless. curves: (name, attrs, t/t* DEM [T], L* DEM [T], t/t* GNS [T'], L* GNS [T']) per case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.plots import save_figure

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for k, (name, attrs, t_dem, runout_dem, t_gns, runout_gns) in enumerate(curves):
        colour = plt.get_cmap("tab10")(k % 10)
        label = f"{name} (mu {float(attrs['friction']):.2f}, a {float(attrs['aspect_ratio']):.2g})"
        ax.plot(t_dem, runout_dem, "-", color=colour, label=f"DEM {label}")
        ax.plot(t_gns, runout_gns, "--", color=colour, label="GNS")
    ax.set(
        xlabel="t / t*",
        ylabel="L* = (L - L_i) / L_i",
        title="runout: DEM (solid) and GNS (dashed)" + (f"\n{runout_label}" if runout_label else ""),
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    save_figure(fig, path)
