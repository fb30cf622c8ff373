"""Figures of the discrepancy diagnosis (read only the Diagnosis, calibration/diagnosis_result.py); the
report section is pipeline/diagnosis_section.py's."""

from __future__ import annotations

import math
import os
from typing import Any

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


def _log_ticks(lo: float, hi: float) -> list[float]:
    """Tick values 1, 2, 5 x 10^k within [lo, hi] (only 1 x 10^k where that spans over 3 decades)."""
    subs = (1, 2, 5) if math.log10(hi / lo) <= 3 else (1,)
    decades = range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1)
    return [m * 10.0**k for k in decades for m in subs if lo <= m * 10.0**k <= hi]


def _runner_up(result: Diagnosis) -> str | None:
    """The candidate with the second-lowest BIC in DEM runs (decide's runner-up); None when only one ran."""
    dem = {n: e.dem.bic for n, e in result.candidates.items() if e.dem is not None}
    ranked = sorted(dem, key=dem.__getitem__)
    return ranked[1] if len(ranked) > 1 else None


def _label_bars(
    ax: plt.Axes, y: np.ndarray, values: list[float], log: bool, clear: dict[int, float] | None = None, **text: Any
) -> None:
    """Each finite value written at the end of its bar, or past x = clear[row] where that lies further out."""
    for row, (yi, v) in enumerate(zip(y, values)):
        if np.isfinite(v):
            right = v >= 0 or log
            x = max(v, (clear or {}).get(row, v)) if right else v
            x = x * 1.04 if log else x
            ax.annotate(
                f"{v:.1f}",
                (x, yi),
                xytext=(3 if right else -3, 0),
                textcoords="offset points",
                ha="left" if right else "right",
                va="center",
                fontsize=7,
                **text,
            )


def _passed(result: Diagnosis, check: str) -> str:
    return "passed" if result.checks.get(check, False) else "FAILED"


def candidates_figure(result: Diagnosis) -> plt.Figure:
    """The figure `plot_candidates` saves (see there); the caller closes it."""
    rule = result.decision_rule
    rows = [result.base] + list(result.candidates.values())
    names = [evidence.model for evidence in rows]
    best, runner_up = result.best_candidate, _runner_up(result)
    base_dem, best_dem = result.base.dem, result.candidates[best].dem
    y = np.arange(len(rows))
    y_best = names.index(best)
    dem_colours = [EXTENDED_COLOUR if n == result.cause else "0.35" for n in names]
    fig, axes = plt.subplots(1, 2, figsize=(14, 0.5 * len(rows) + 3.4))

    # -- BIC, as the rule reads it: how far below the base model's (in DEM runs) ------------------------
    ax = axes[0]
    emulated = [np.nan] + [result.base.emulator.bic - e.emulator.bic for e in rows[1:]]
    dem = [np.nan] + [base_dem.bic - e.dem.bic if e.dem else np.nan for e in rows[1:]]
    ax.barh(y + 0.2, emulated, height=0.38, color="0.8", label="emulator")
    ax.barh(y - 0.2, dem, height=0.38, color=dem_colours, label="DEM runs (the rule reads these)")
    _label_bars(ax, y + 0.2, emulated, log=False, color="0.45")
    needed = np.nan
    values = [v for v in emulated + dem if np.isfinite(v)] + [rule.min_delta_bic_vs_base]
    lo, hi = min(0.0, min(values)), max(values)
    ax.set_xlim(lo - 0.12 * (hi - lo) * (lo < 0), hi + 0.12 * (hi - lo))
    left_half = ax.transLimits.transform((rule.min_delta_bic_vs_base, 0))[0] < 0.5
    ax.annotate(
        f"reference: BIC {base_dem.bic:.1f} (DEM), {result.base.emulator.bic:.1f} (emulator)",
        (rule.min_delta_bic_vs_base, 0),
        xytext=(5 if left_half else -5, 0),
        textcoords="offset points",
        ha="left" if left_half else "right",
        va="center",
        fontsize=8,
        color="0.3",
    )
    ax.axvline(0, color="k", lw=0.6)
    ax.axvline(
        rule.min_delta_bic_vs_base,
        color="tab:red",
        ls="--",
        lw=1.2,
        label=f"ΔBIC vs base ≥ {rule.min_delta_bic_vs_base:g} to name a cause "
        f"({best}: {base_dem.bic - best_dem.bic:.1f}, {_passed(result, 'bic_beats_base')})",
    )
    if runner_up is not None:
        needed = base_dem.bic - result.candidates[runner_up].dem.bic + rule.min_delta_bic_vs_runner_up
        ax.plot(
            [needed, needed],
            [y_best - 0.45, y_best + 0.05],
            color="tab:purple",
            lw=2,
            label=f"{best} must beat the runner-up, {runner_up}, by ΔBIC ≥ {rule.min_delta_bic_vs_runner_up:g}: "
            f"≥ {needed:.1f} ({_passed(result, 'bic_beats_runner_up')})",
        )
    _label_bars(ax, y - 0.2, dem, log=False, clear={y_best: needed})
    ax.set(
        xlabel="ΔBIC vs base = BIC(base) − BIC(model)  (dimensionless; higher is better)",
        title="BIC below the base model's (fit + complexity)",
    )

    # -- held-out chi^2, log scale: the base model's is the reference of the gain -------------------------
    ax = axes[1]
    emulated = [e.emulator.heldout_chi2 for e in rows]
    dem = [e.dem.heldout_chi2 if e.dem else np.nan for e in rows]
    ax.barh(y + 0.2, emulated, height=0.38, color="0.8", label="emulator")
    ax.barh(y - 0.2, dem, height=0.38, color=dem_colours, label="DEM runs (the rule reads these)")
    _label_bars(ax, y + 0.2, emulated, log=True, color="0.45")
    gain_line = (1 - rule.min_heldout_gain) * base_dem.heldout_chi2
    ax.axvline(
        gain_line,
        color="tab:red",
        ls="--",
        lw=1.2,
        label=f"held-out gain ≥ {rule.min_heldout_gain:g}: χ² ≤ {1 - rule.min_heldout_gain:g} × base's = "
        f"{gain_line:.1f} ({best}: {best_dem.heldout_chi2:.1f}, {_passed(result, 'heldout_beats_base')})",
    )
    if runner_up is not None:
        tie = rule.heldout_tie_sd * math.sqrt(2 * best_dem.n_heldout)
        allowed = result.candidates[runner_up].dem.heldout_chi2 + tie
        ax.plot(
            [allowed, allowed],
            [y_best - 0.45, y_best + 0.05],
            color="tab:purple",
            lw=2,
            label=f"{best} no worse than the runner-up, {runner_up}, beyond {rule.heldout_tie_sd:g} sd "
            f"(+{tie:.1f}): ≤ {allowed:.1f} ({_passed(result, 'heldout_no_worse_than_runner_up')})",
        )
    else:
        allowed = np.nan
    _label_bars(ax, y - 0.2, dem, log=True, clear={y_best: allowed})
    values = [v for v in emulated + dem + [gain_line, allowed] if np.isfinite(v) and v > 0]
    lo, hi = min(values) / 1.5, max(values) * 1.8
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    ax.xaxis.set_major_locator(matplotlib.ticker.FixedLocator(_log_ticks(lo, hi)))
    ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set(
        xlabel="held-out χ² against the noise + the fold fit's parameter spread (dimensionless; log; lower is better)",
        title=f"held-out χ² ({best_dem.n_heldout} values predicted from fits without them)",
    )

    best_label = f"{best}\n({'the cause' if result.cause == best else 'best in DEM, not named'})"
    for ax in axes:
        ax.set_yticks(y, [best_label if n == best else n for n in names])
        ax.get_yticklabels()[y_best].set_fontweight("bold")
        ax.set_ylim(len(rows) - 0.4, -0.6)
        ax.grid(alpha=0.3, axis="x")
        ax.legend(fontsize=7.5, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=1, frameon=False)
    failed = [k for k, ok in result.checks.items() if not ok]
    fits = "misfits beyond" if base_dem.p_value < rule.misfit_p_value else "fits within"
    fig.suptitle(
        f"{result.name or 'diagnosis'}: cause = {result.cause}  "
        f"({'every check passed' if not failed else 'failed: ' + ', '.join(failed)})\n"
        f"the base model {fits} the noise in DEM runs (p = {base_dem.p_value:.2g}, "
        f"threshold {rule.misfit_p_value:g}; reported, not required); the thresholds apply to the DEM runs "
        f"of the best candidate",
        fontsize=9,
    )
    fig.tight_layout()
    return fig


def plot_candidates(result: Diagnosis, path: str | os.PathLike) -> None:
    """Evidence per model, on its emulator (light) and in DEM runs (dark: the base model and the
    leading candidates; the cause coloured): the BIC below the base model's and the held-out chi^2,
    with the decision rule's thresholds (calibration/decision.py) drawn where they fall: dashed
    against the base model, solid on the best candidate's row against the runner-up. Saved to `path`."""
    save_figure(candidates_figure(result), path)
