"""Figures of a collapse: snapshots at chosen t/t* and the runout curve (DEM and GNS alike)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import EllipseCollection  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from dem.atomic import atomic_path  # noqa: E402
from dem.runout import RunoutMethod  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from dem.trajectory import Trajectory

SNAPSHOT_TSTAR = (0.0, 1.0, 1.5, 2.0, 4.0)


def draw_grains(
    ax: Axes, positions: np.ndarray, radius: np.ndarray, color: str = "tab:orange", alpha: float = 1.0
) -> None:
    """Discs at their true size (data units) on `ax`. positions [N, 2] (m), radius [N] (m)."""
    diameters = 2 * np.asarray(radius)
    ax.add_collection(
        EllipseCollection(
            diameters,
            diameters,
            np.zeros_like(diameters),
            units="xy",
            offsets=np.asarray(positions),
            offset_transform=ax.transData,
            facecolors=color,
            edgecolors="none",
            alpha=alpha,
        )
    )


def case_title(attrs: dict, length: bool = True) -> str:
    """A figure title naming a collapse case by its trajectory attrs: material, aspect ratio a,
    initial column length L_i (shown in mm; attrs in m) when `length`, friction mu, restitution e."""
    size = f", L_i = {float(attrs['L_i']) * 1e3:.3g} mm" if length else ""
    return (
        f"{attrs.get('material')} a = {float(attrs['aspect_ratio']):.3g}{size}, "
        f"mu = {float(attrs['friction']):.3g}, e = {float(attrs['restitution']):.3g}"
    )


def save_figure(fig: Figure, path: str | os.PathLike) -> None:
    """Save atomically (the format follows the path's suffix) and close."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=str(path).rsplit(".", 1)[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)


def plot_case(
    trajectory: Trajectory,
    path: str | os.PathLike,
    runout: RunoutMethod | dict | str,
    compare: Trajectory | None = None,
    snapshots: Sequence[float] = SNAPSHOT_TSTAR,
) -> None:
    """Snapshots at t/t* in `snapshots` and the runout curve L*(t/t*) read by `runout` (a
    dem.runout.RunoutMethod, config dict or name); `compare` (another trajectory of the same case,
    e.g. a GNS rollout) is drawn over it in blue."""
    runout = RunoutMethod.from_config(runout)
    t_over_tstar = trajectory.t_over_tstar
    shown = [t for t in snapshots if t <= t_over_tstar[-1] + 1e-9]
    fig, axes = plt.subplots(len(shown) + 1, 1, figsize=(8, 1.6 * len(shown) + 3))
    extent = max(float(trajectory.positions[-1, :, 0].max()), float(trajectory.attrs["L_i"])) * 1.15
    height = float(trajectory.positions[0, :, 1].max()) * 1.1
    for ax, t in zip(axes, shown):
        k = int(np.argmin(np.abs(t_over_tstar - t)))
        draw_grains(ax, trajectory.positions[k], trajectory.radius)
        if compare is not None:
            kc = min(k, compare.n_frames - 1)
            draw_grains(ax, compare.positions[kc], compare.radius, color="tab:blue", alpha=0.5)
        ax.axvline(float(trajectory.attrs["L_i"]), color="0.6", lw=0.8, ls=":")
        ax.set(xlim=(0, extent), ylim=(0, height), aspect="equal")
        ax.set_title(f"t/t* = {t_over_tstar[k]:.2f}", fontsize=9, loc="left")
        ax.tick_params(labelsize=7)
    engines = [(trajectory.attrs["engine"], "tab:orange")]
    if compare is not None:
        engines.append((compare.attrs["engine"], "tab:blue"))
    axes[0].legend(handles=[Patch(color=c, label=name) for name, c in engines], loc="upper right", fontsize=7)
    ax = axes[-1]
    for traj, style in ((trajectory, "-"), (compare, "--")):
        if traj is not None:
            t, curve = runout.curve(traj)
            ax.plot(t, curve, style, label=traj.attrs["engine"])
    ax.set(xlabel="t / t*", ylabel="L* = (L - L_i) / L_i")
    ax.set_title(runout.label, fontsize=8, loc="left")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.suptitle(case_title(trajectory.attrs), fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
