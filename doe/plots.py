"""DoE figures: fitted response surfaces with the design points and optimum, and runout curves
before/after calibration against the measured points (the paper's Fig. 11)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from dem.plots import plt, save_figure

if TYPE_CHECKING:
    import pandas as pd

    from calibration.measured import MeasuredColumn

SURFACE_POINTS = 101  # per axis


def plot_response_surfaces(
    fits: dict, responses: pd.DataFrame, path: str | os.PathLike, response: str = "mse", measured_name: str = ""
) -> None:
    """One panel per fitted model: predicted response over the two factors (natural units), the
    design points coloured by their observed response, and the model's optimum (star).

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
    low = min(observed.min(), *(s.min() for s in surfaces.values()))
    high = max(observed.max(), *(s.max() for s in surfaces.values()))
    levels = np.linspace(low, high, 21)
    fig, axes = plt.subplots(1, len(fits), figsize=(5.2 * len(fits), 4.4), squeeze=False)
    for ax, (model, fit) in zip(axes[0], fits.items()):
        shading = ax.contourf(fx.decode(gx), fy.decode(gy), surfaces[model], levels=levels, cmap="viridis")
        ax.contour(fx.decode(gx), fy.decode(gy), surfaces[model], levels=levels[::2], colors="w", linewidths=0.4)
        ax.scatter(
            responses[fx.name],
            responses[fy.name],
            c=observed,
            cmap="viridis",
            vmin=low,
            vmax=high,
            edgecolors="k",
            s=36,
            zorder=3,
            label="DEM runs (observed)",
        )
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


def plot_runout_comparison(measured: MeasuredColumn, curves: dict, path: str | os.PathLike, title: str = "") -> None:
    """Runout L*(t/t*) of simulated runs against the measured points (Fig. 11 of the paper).

    measured: calibration.measured.MeasuredColumn; curves: {label: (t_over_tstar [T], L* [T])}.
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
