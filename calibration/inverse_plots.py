"""Figures of the GNS inverse design (calibration.inverse): the optimisation paths of every start
over the objective landscape (the paper's Fig. 2) and the GNS deposits for labelled parameter sets
(the paper's Fig. 9).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence

import numpy as np
import torch

from calibration.gns_objective import GNSObjective


def _ellipse(ax, centre, covariance, colour="w"):
    """95% credible ellipse of a 2-parameter Gaussian posterior."""
    from matplotlib.patches import Ellipse
    from scipy.stats import chi2

    values, vectors = np.linalg.eigh(np.asarray(covariance, float))
    scale = math.sqrt(chi2.ppf(0.95, 2))
    width, height = 2 * scale * np.sqrt(np.maximum(values, 0))
    angle = math.degrees(math.atan2(vectors[1, 1], vectors[0, 1]))
    ax.add_patch(
        Ellipse(centre, height, width, angle=angle, fill=False, ec=colour, lw=1.2, ls="--", label="95% credible region")
    )


def plot_paths(
    result: dict,
    path: str | os.PathLike,
    dem_points: Mapping[str, Sequence[float] | np.ndarray] | None = None,
    title: str = "",
) -> None:
    """The optimisation paths of every start over the objective landscape (the paper's Fig. 2).

    result: InverseResult.to_dict(); its GNS landscape (if computed) is the background. dem_points:
    optional DEM objective values {"friction": [n], "restitution": [n], "mse": [n]} (e.g. the
    DoE runs), drawn as squares coloured on the same scale. The posterior's 95% region is dashed.
    """
    from dem.plots import plt, save_figure

    names = result["names"]
    if len(names) != 2:  # no plane to draw the paths in: each parameter against the iteration
        return plot_traces(result, path, title)
    (x_low, x_high), (y_low, y_high) = result["bounds"]
    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    values = [v for s in result["starts"] for v in s["evaluations"]["values"]]
    if dem_points is not None:
        values += list(dem_points["mse"])
    grid = result.get("landscape")
    if grid:
        values += [v for row in grid["values"] for v in row]
    finite = np.array([v for v in values if np.isfinite(v)])
    norm = plt.matplotlib.colors.LogNorm(max(finite.min(), 1e-4), max(finite.max(), 1e-3))
    if grid:
        shade = ax.contourf(
            grid["axes"][0],
            grid["axes"][1],
            np.maximum(grid["values"], norm.vmin),
            levels=np.geomspace(norm.vmin, norm.vmax, 16),
            norm=norm,
            cmap="viridis",
        )
        fig.colorbar(shade, ax=ax, label="objective (runout MSE), GNS landscape")
    if dem_points is not None:
        dots = ax.scatter(
            dem_points[names[0]],
            dem_points[names[1]],
            c=np.maximum(dem_points["mse"], norm.vmin),
            norm=norm,
            cmap="viridis",
            marker="s",
            s=40,
            edgecolors="0.3",
            label="DEM runs (DoE)",
        )
        if not grid:
            fig.colorbar(dots, ax=ax, label="objective (runout MSE), DEM")
    for k, start in enumerate(result["starts"]):
        points = np.array([p["params"] for p in start["iterates"]])
        colour = plt.get_cmap("tab10")(k % 10)
        ax.plot(points[:, 0], points[:, 1], "-", color=colour, lw=1.2)
        for a, b in zip(points[:-1], points[1:]):
            ax.annotate("", b, a, arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.2})
        ax.plot(*points[0], "o", color="k", ms=6, zorder=4)
        ax.plot(
            *points[-1],
            "o",
            color=colour,
            mec="k",
            ms=6,
            zorder=4,
            label=f"start {k + 1}: {start['iterates'][0]['value']:.3g} -> {start['value']:.3g}",
        )
    best = result["best_params"]
    ax.plot(*best, "r*", ms=16, mec="w", zorder=5, label=f"optimum ({best[0]:.3f}, {best[1]:.3f})")
    _ellipse(ax, best, result["posterior"]["covariance"], colour="r")
    if dem_points is not None:  # the DEM runs may lie beyond the GNS's (trained-range) bounds
        x_low, x_high = min(x_low, np.min(dem_points[names[0]])), max(x_high, np.max(dem_points[names[0]]))
        y_low, y_high = min(y_low, np.min(dem_points[names[1]])), max(y_high, np.max(dem_points[names[1]]))
        ax.add_patch(
            plt.Rectangle(
                (result["bounds"][0][0], result["bounds"][1][0]),
                np.diff(result["bounds"][0])[0],
                np.diff(result["bounds"][1])[0],
                fill=False,
                ec="0.4",
                ls=":",
                lw=1,
                label="GNS bounds",
            )
        )
    pad = 0.02
    ax.set(
        xlim=(x_low - pad, x_high + pad),
        ylim=(y_low - pad, y_high + pad),
        xlabel=f"{names[0]}",
        ylabel=f"{names[1]}",
        title=title or f"GNS inverse design of {result['measured']} ({result['gradient']} gradients)",
    )
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    save_figure(fig, path)


def plot_traces(result: dict, path: str | os.PathLike, title: str = "") -> None:
    """The optimisation paths of every start, one panel per design parameter (any number of them):
    the parameter at each iteration, the bounds as the panel's limits, the optimum with its 95%
    posterior interval; the last panel is the objective per iteration."""
    from dem.plots import plt, save_figure

    names, bounds = result["names"], result["bounds"]
    posterior = {p["name"]: p for p in result["posterior"]["parameters"]}
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(3.2 * (len(names) + 1), 3.4))
    for k, start in enumerate(result["starts"]):
        colour = plt.get_cmap("tab10")(k % 10)
        points = np.array([p["params"] for p in start["iterates"]])
        values = [p["value"] for p in start["iterates"]]
        for j, ax in enumerate(axes[:-1]):
            ax.plot(points[:, j], "o-", color=colour, ms=3, lw=1)
        axes[-1].semilogy(
            values, "o-", color=colour, ms=3, lw=1, label=f"start {k + 1}: {values[0]:.3g} -> {values[-1]:.3g}"
        )
    for j, (ax, name) in enumerate(zip(axes, names)):
        p = posterior.get(name)
        if p is not None:
            ax.axhspan(p["low"], p["high"], color="r", alpha=0.12, label="95% interval")
        ax.axhline(result["best_params"][j], color="r", lw=1.2, label=f"optimum {result['best_params'][j]:.3g}")
        ax.set(ylim=bounds[j], xlabel="iteration", ylabel=name)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1].set(xlabel="iteration", ylabel="objective (runout MSE), GNS")
    axes[-1].legend(fontsize=7)
    axes[-1].grid(alpha=0.3)
    fig.suptitle(title or f"GNS inverse design of {result['measured']} ({result['gradient']} gradients)", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def plot_deposits(objective: GNSObjective, params: dict, path: str | os.PathLike, title: str = "") -> None:
    """GNS deposits at the last measured t/t* for each labelled parameter set (the paper's Fig. 9):
    params {label: [P]}; the measured final runout is the dashed line. An objective of several
    start packings draws its first."""
    from dem.plots import draw_grains, plt, save_figure

    labels = list(params)
    theta = objective._theta(np.array([params[k] for k in labels]))
    from gns.rollout import rollout
    from gns.runout import frame_weights

    with torch.no_grad():
        result = rollout(
            objective.simulator,
            objective.initial.repeat(1, len(labels), 1),
            objective._context(theta),
            objective.n_steps,
            checkpoint=False,
        )
    t_last = float(objective.measured.t_over_tstar[-1])
    k, w = frame_weights([t_last], objective.t_star, objective.dt_frame, result.positions.shape[0])[0]
    frame = int(k + round(w))
    first = objective.packing_sizes[0]
    positions = result.positions[frame].reshape(len(labels), objective.n_particles, 2)[:, :first].cpu().numpy()
    radius = objective.radius[:first].cpu().numpy()
    measured_front = objective.L_i * (1 + float(objective.measured.runout[-1]))
    extent = max(float(positions[..., 0].max()), measured_front) * 1.1
    height = float(objective.initial[0, :first, 1].max()) * 0.6 + 4 * float(radius.max())
    fig, axes = plt.subplots(len(labels), 1, figsize=(8, 1.2 + 1.3 * len(labels)), squeeze=False)
    for ax, label, frame_positions in zip(axes[:, 0], labels, positions):
        draw_grains(ax, frame_positions, radius, color="tab:blue")
        ax.axvline(
            measured_front, color="0.4", ls="--", lw=1, label=f"measured L* = {objective.measured.runout[-1]:.3g}"
        )
        ax.axvline(objective.L_i, color="0.7", ls=":", lw=0.8)
        ax.set(xlim=(0, extent), ylim=(0, height), aspect="equal")
        ax.set_title(
            f"{label}: "
            + ", ".join(f"{n} = {v:.3f}" for n, v in zip(objective.design_names, params[label]))
            + f"  (t/t* = {frame * objective.dt_frame / objective.t_star:.2f})",
            fontsize=8,
            loc="left",
        )
        ax.tick_params(labelsize=6)
    axes[0, 0].legend(fontsize=7, loc="upper right")
    fig.suptitle(title or f"GNS deposits during the inverse design of {objective.measured.name}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def plot_sensitivity(result: dict, path: str | os.PathLike, title: str = "") -> None:
    """Does the GNS see each parameter (calibration.sensitivity): the last measured L* against each
    design parameter, the DEM runs of the GNS's dataset beside the GNS's points of the inverse
    design, each with the slope of its plane fit across the bounds; result: InverseResult.to_dict()
    with its sensitivity."""
    from dem.plots import plt, save_figure

    data, names, bounds = result["sensitivity"], result["names"], result["bounds"]
    fig, axes = plt.subplots(1, len(names), figsize=(3.4 * len(names), 3.4), squeeze=False)
    if not data["parameters"]:  # not checked (too few DEM runs or GNS points): the points and why
        responses = [{"dem": None, "gns": None, "resolved": "unchecked"} for _ in names]
        fig.text(0.5, 0.5, data["why"], ha="center", va="center", fontsize=8, wrap=True, color="r")
    else:
        responses = data["parameters"]
    for j, (ax, name, response) in enumerate(zip(axes[0], names, responses)):
        for key, colour, label in (("dem", "k", "DEM runs of the dataset"), ("gns", "tab:orange", "GNS points")):
            points, last = np.asarray(data[key]["points"], float), np.asarray(data[key]["last"], float)
            ran = np.isfinite(last)  # a failed rollout (null) is no point, as in the fit
            points, last = points[ran], last[ran]
            ax.plot(points[:, j], last, "o", color=colour, ms=3, alpha=0.7, label=label)
            centre, slope = np.mean(points[:, j]), response[key]
            if slope is None:
                continue
            x = np.array(bounds[j], float)
            u = (x - centre) / (x[1] - x[0])
            # the plane fit's slope in this parameter, drawn through the points' mean
            ax.plot(
                x,
                np.mean(last) + slope * u,
                "-",
                color=colour,
                lw=1.2,
                label=f"{slope:+.2f} +- {response[key + '_se']:.2f}",
            )
        verdict = {True: "resolved", False: "NOT resolved", None: "DEM flat or unsure", "unchecked": "not checked"}[
            response["resolved"]
        ]
        if response.get("gns_only"):
            verdict = "DEM flat, GNS responds"
        ax.set(xlim=bounds[j], xlabel=name, ylabel="L* at the last measured t/t*")
        ax.set_title(f"{name}: {verdict}", fontsize=9)
        ax.legend(fontsize=6)
        ax.grid(alpha=0.3)
    fig.suptitle(title or f"does the GNS see each parameter? ({result['measured']})", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
