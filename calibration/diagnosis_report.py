"""Figures of the discrepancy diagnosis (read only the Diagnosis, calibration/diagnosis_result.py); the
report section is pipeline/diagnosis.py's."""

from __future__ import annotations

import os

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calibration.diagnosis_result import Diagnosis  # noqa: E402
from dem.plots import save_figure  # noqa: E402

PHASE_EDGES = (1.0, 2.5)  # t/t*: the paper's free-fall | spreading | stopping phases
BASE_COLOUR, EXTENDED_COLOUR = "tab:orange", "tab:blue"


def _compared(result: Diagnosis) -> str:
    """The extension drawn beside the base model: the cause, else the best candidate."""
    return result.cause if result.cause != "none" else result.best_candidate


def plot_residuals(result: Diagnosis, path: str | os.PathLike) -> None:
    """Per measured column: runout (measured, base and extended DEM runs), the base model's
    normalised residuals by time phase, and the deposit profile when measured; saved to `path`."""
    labels = result.observables.labels
    measured = result.observables.measured
    base = result.base.dem
    other_name = _compared(result)
    other = result.candidates[other_name].dem
    sigma = base.sigma
    columns = [c.name for c in result.columns]
    has_profile = any(kind == "profile" for _, kind, _ in labels)
    fig, axes = plt.subplots(
        len(columns), 3 if has_profile else 2, figsize=(13 if has_profile else 9, 3.2 * len(columns)), squeeze=False
    )
    for row, name in enumerate(columns):
        runout = np.array([lab[0] == name and lab[1] == "runout" for lab in labels])
        profile = np.array([lab[0] == name and lab[1] == "profile" for lab in labels])
        t = np.array([lab[2] for lab in labels])[runout]
        ax = axes[row, 0]
        for k, curves in enumerate(base.curves):
            ax.plot(*curves[row], color=BASE_COLOUR, lw=1, alpha=0.7, label="base model (DEM)" if k == 0 else None)
        for k, curves in enumerate(other.curves):
            ax.plot(
                *curves[row],
                color=EXTENDED_COLOUR,
                lw=1,
                ls="--",
                alpha=0.8,
                label=f"+ {other_name} (DEM)" if k == 0 else None,
            )
        ax.errorbar(t, measured[runout], yerr=sigma[runout], fmt="o", color="k", ms=3, capsize=2, label="measured")
        ax.set(xlabel="t / t*", ylabel="L*", title=f"{name}: runout")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        ax = axes[row, 1]
        z_base = (base.observed_mean - measured) / sigma
        z_other = (other.observed_mean - measured) / other.sigma
        ax.axvspan(0, PHASE_EDGES[0], color="0.93")
        ax.axvspan(PHASE_EDGES[1], max(t.max(), PHASE_EDGES[1]) + 0.5, color="0.93")
        ax.bar(t, z_base[runout], width=0.18, color=BASE_COLOUR, label="base model")
        ax.plot(t, z_other[runout], "s", mfc="none", color=EXTENDED_COLOUR, label=f"+ {other_name}")
        for level in (-2, 2):
            ax.axhline(level, color="0.5", ls=":", lw=0.8)
        ax.axhline(0, color="k", lw=0.6)
        ax.set(
            xlabel="t / t*  (shaded: free-fall | stopping phase)",
            ylabel="(simulated - measured) / sigma",
            title="runout residuals, normalised by the noise",
        )
        ax.legend(fontsize=7)
        if has_profile:
            ax = axes[row, 2]
            if profile.any():
                x = np.array([lab[2] for lab in labels])[profile] * 1e3
                ax.errorbar(
                    x,
                    measured[profile] * 1e3,
                    yerr=sigma[profile] * 1e3,
                    fmt="o",
                    color="k",
                    ms=3,
                    capsize=2,
                    label="measured",
                )
                ax.plot(x, base.observed_mean[profile] * 1e3, "-", color=BASE_COLOUR, label="base model")
                ax.plot(
                    x,
                    other.observed_mean[profile] * 1e3,
                    "--",
                    color=EXTENDED_COLOUR,
                    label=f"+ {other_name}",
                )
                ax.legend(fontsize=7)
            ax.set(xlabel="x (mm)", ylabel="deposit height (mm)", title="deposit profile (last frame)")
            ax.grid(alpha=0.3)
    fig.suptitle(
        f"{result.name or 'diagnosis'}: cause = {result.cause}   "
        f"(base model chi^2 = {base.chi2:.1f} for {base.n_data} values, p = {base.p_value:.2g})",
        fontsize=10,
    )
    fig.tight_layout()
    save_figure(fig, path)


def plot_candidates(result: Diagnosis, path: str | os.PathLike) -> None:
    """Evidence per model: BIC and held-out chi^2 on its emulator (light) and in DEM runs (dark,
    the base model and the leading candidates), lower is better; the cause is outlined. Saved to `path`."""
    rows = [result.base] + list(result.candidates.values())
    names = [evidence.model for evidence in rows]
    y = np.arange(len(rows))
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.45 * len(rows) + 2.2))
    for ax, key, title in ((axes[0], "bic", "BIC (fit + complexity)"), (axes[1], "heldout_chi2", "held-out chi^2")):
        emulated = [getattr(evidence.emulator, key) for evidence in rows]
        dem = [getattr(evidence.dem, key) if evidence.dem else np.nan for evidence in rows]
        ax.barh(y + 0.2, emulated, height=0.38, color="0.8", label="emulator")
        ax.barh(
            y - 0.2,
            dem,
            height=0.38,
            color=[EXTENDED_COLOUR if n == result.cause else "0.35" for n in names],
            label="DEM runs",
        )
        ax.set_yticks(y, names)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set(xlabel=f"{title}, lower is better", title=title)
        ax.invert_yaxis()
        ax.grid(alpha=0.3, axis="x")
        ax.legend(fontsize=7)
    rule = result.decision_rule
    fig.suptitle(
        f"{result.name or 'diagnosis'}: cause = {result.cause}  (rule: BIC {rule.min_delta_bic_vs_base:g} "
        f"below the base model and {rule.min_delta_bic_vs_runner_up:g} below the runner-up, held-out chi^2 "
        f"{100 * rule.min_heldout_gain:.0f}% below the base model's and no worse than the runner-up's "
        f"beyond {rule.heldout_tie_sd:g} sd)",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)
