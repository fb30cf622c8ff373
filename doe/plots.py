"""DoE figures: fitted response surfaces with the design points and optimum (two factors; or every
pair of k factors, the others held at the optimum), and runout curves before/after calibration
against the measured points (the paper's Fig. 11)."""

from __future__ import annotations

import itertools
import os
from typing import TYPE_CHECKING

import numpy as np

from dem.plots import plt, save_figure

if TYPE_CHECKING:
    import pandas as pd

    from calibration.measured_column import MeasuredColumn
    from doe.regression import SurfaceFit

SURFACE_POINTS = 101  # per axis


def plot_response_surfaces(
    fits: dict, responses: pd.DataFrame, path: str | os.PathLike, response: str = "mse", measured_name: str = ""
) -> None:
    """One panel per fitted model: predicted response over the two factors (natural units), the
    design points coloured by their observed response (a run without a finite response, a failed
    DEM run, as a red cross), and the model's optimum (star).

    fits: {model: doe.regression.SurfaceFit} over the same two factors; responses: DataFrame with
    the factor columns and `response`.
    """
    fits = dict(fits)
    first = next(iter(fits.values()))
    fx, fy = first.factors
    axis = np.linspace(-1, 1, SURFACE_POINTS)
    gx, gy = np.meshgrid(axis, axis, indexing="xy")
    observed = responses[response].to_numpy(float)
    surfaces = {m: f.predict(np.column_stack([gx.ravel(), gy.ravel()])).reshape(gx.shape) for m, f in fits.items()}
    levels = _levels(observed, surfaces.values())
    fig, axes = plt.subplots(1, len(fits), figsize=(5.2 * len(fits), 4.4), squeeze=False)
    for ax, (model, fit) in zip(axes[0], fits.items()):
        label = "DEM runs (observed)"
        shading = _surface_panel(ax, fx, fy, gx, gy, surfaces[model], levels, responses, observed, label)
        best = fit.optimum()["natural"]
        ax.plot(
            best[fx.name],
            best[fy.name],
            "r*",
            ms=16,
            mec="w",
            zorder=4,
            label=f"optimum ({best[fx.name]:.2f}, {best[fy.name]:.2f})",
        )
        ax.set(
            xlabel=f"{fx.name}",
            ylabel=f"{fy.name}",
            xlim=(fx.low, fx.high),
            ylim=(fy.low, fy.high),
            title=f"{model}: R$^2$ = {fit.r_squared:.2f}",
        )
        ax.legend(fontsize=7, loc="upper right")
    fig.colorbar(shading, ax=axes[0].tolist(), label=f"{response} (fitted surface and runs)")
    fig.suptitle(f"DoE response surfaces{' - ' + measured_name if measured_name else ''}", fontsize=10)
    save_figure(fig, path)


def plot_surface_pairs(
    fit: SurfaceFit, responses: pd.DataFrame, path: str | os.PathLike, response: str = "mse", title: str = ""
) -> None:
    """One contour panel per pair of the fit's k factors (natural units): the fitted surface with
    the other factor(s) held at the fit's optimum, every design run projected onto the pair and
    coloured by its observed response (a run without a finite response, e.g. a failed DEM run, as
    a red cross), and the optimum (star).

    fit: doe.regression.SurfaceFit over k >= 2 factors; responses: the factor columns and `response`.
    """
    optimum = fit.optimum()
    natural = optimum["natural"]
    best = np.array([optimum["coded"][f.name] for f in fit.factors])
    pairs = list(itertools.combinations(range(len(fit.factors)), 2))
    axis = np.linspace(-1, 1, SURFACE_POINTS)
    gx, gy = np.meshgrid(axis, axis, indexing="xy")
    surfaces = []
    for i, j in pairs:
        coded = np.tile(best, (gx.size, 1))
        coded[:, i], coded[:, j] = gx.ravel(), gy.ravel()
        surfaces.append(fit.predict(coded).reshape(gx.shape))
    observed = responses[response].to_numpy(float)
    levels = _levels(observed, surfaces)
    fig, axes = plt.subplots(1, len(pairs), figsize=(4.8 * len(pairs) + 1.0, 4.8), squeeze=False, layout="constrained")
    for ax, (i, j), surface in zip(axes[0], pairs, surfaces):
        fx, fy = fit.factors[i], fit.factors[j]
        # design runs and optimum sit on the bounds: drawn whole over the frame (clip_on=False)
        label = "DEM runs (observed, projected onto the panel)"
        shading = _surface_panel(ax, fx, fy, gx, gy, surface, levels, responses, observed, label, clip_on=False)
        ax.plot(natural[fx.name], natural[fy.name], "r*", ms=16, mec="w", zorder=5, clip_on=False, label="optimum")
        held = ", ".join(f"{f.name} = {natural[f.name]:.3g}" for k, f in enumerate(fit.factors) if k not in (i, j))
        ax.set(xlabel=fx.name, ylabel=fy.name, xlim=(fx.low, fx.high), ylim=(fy.low, fy.high))
        ax.set_title(f"held at the optimum: {held}" if held else "", fontsize=9)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=8)
    fig.colorbar(shading, ax=axes[0].tolist(), label=f"{response} (fitted {fit.model} surface and runs)")
    at = ", ".join(f"{name} = {value:.3g}" for name, value in natural.items())
    heading = (
        f"{fit.model} response surface (R$^2$ = {fit.r_squared:.2f}); optimum {at}, "
        f"predicted {response} {optimum['predicted']:.3g}"
    )
    fig.suptitle(f"{title}\n{heading}" if title else heading, fontsize=10)
    save_figure(fig, path)


def _levels(observed: np.ndarray, surfaces) -> np.ndarray:
    """21 contour levels over the finite observed responses and every fitted surface: one colour
    scale for every panel and the runs, so that panels compare."""
    ran = observed[np.isfinite(observed)]
    low = min(ran.min(initial=np.inf), *(s.min() for s in surfaces))
    high = max(ran.max(initial=-np.inf), *(s.max() for s in surfaces))
    return np.linspace(low, high, 21)


def _surface_panel(ax, fx, fy, gx, gy, surface, levels, responses, observed, label: str, clip_on: bool = True):
    """One panel: the fitted `surface` [G, G] over the coded grid (gx, gy) in natural units, filled
    and contoured at `levels`, and the design runs coloured by their `observed` response on the same
    scale (a run without a finite response as a red cross). Returns the filled contour set."""
    shading = ax.contourf(fx.decode(gx), fy.decode(gy), surface, levels=levels, cmap="viridis")
    ax.contour(fx.decode(gx), fy.decode(gy), surface, levels=levels[::2], colors="w", linewidths=0.4)
    x, y = responses[fx.name].to_numpy(float), responses[fy.name].to_numpy(float)
    ran = np.isfinite(observed)
    scale = dict(cmap="viridis", vmin=levels[0], vmax=levels[-1], edgecolors="k", s=36, zorder=3)
    ax.scatter(x[ran], y[ran], c=observed[ran], clip_on=clip_on, label=label, **scale)
    if not ran.all():
        ax.plot(x[~ran], y[~ran], "rx", ms=10, mew=2, zorder=4, clip_on=clip_on, label="failed DEM runs")
    return shading


def plot_runout_comparison(measured: MeasuredColumn, curves: dict, path: str | os.PathLike, title: str = "") -> None:
    """Runout L*(t/t*) of simulated runs against the measured points (Fig. 11 of the paper).

    measured: calibration.measured_column.MeasuredColumn; curves: {label: (t_over_tstar [T], L* [T])}.
    Error bars show the measured noise level where the file gives one.
    """
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for label, (t, runout) in curves.items():
        ax.plot(t, runout, lw=1.6, label=label)
    ax.errorbar(
        measured.t_over_tstar,
        measured.runout,
        yerr=measured.runout_std,
        fmt="ko",
        ms=6,
        capsize=3,
        label=f"measured ({measured.name})",
        zorder=5,
    )
    ax.set(xlabel="t / t*", ylabel="L* = (L - L_i) / L_i", xlim=(0, None), ylim=(0, None))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(
        title or f"{measured.material}, a = {measured.aspect_ratio:g}, L_i = {measured.L_i * 1e3:g} mm", fontsize=10
    )
    fig.tight_layout()
    save_figure(fig, path)
