"""Parameter recovery on synthetic targets: DEM runs with known (mu, e), not in the GNS's training
set, serve as "measured" curves with noise; the GNS inverse design must find mu again.

Protocol (guided by benchmarks/recovery_feasibility.py). A DEM runout curve of one packing is
one random draw: on the quartz a = 6 column at 589 grains its L* scatters between packings by
0.04 (t/t* = 0.5) to 0.4 (t/t* = 3.5), about what mu moves it by over 0.1 to 0.3 (friction
saturates above mu ~ 0.6). So a target, like a lab result from repeated tests, is the MEAN runout
of `packings` DEM runs of the GNS dataset's own column (same material, geometry, grain size and
frame interval; each its own packing seed) at the chosen t/t* points, plus Gaussian measurement
noise of known std. Its stated std is that of such a mean: sqrt(noise^2 + s_p^2 / k), with s_p the
packing scatter pooled over all targets (each target's own mean removed). The inverse design
starts every rollout from the first frames of a reference run at the paper's start point (another
packing, as a real measurement would have), so its prediction is one packing's: s_p joins the
posterior's noise model on the model side as well (calibration.inverse.noise_level), and the
95% intervals carry the packing scatter instead of pretending the runout is a smooth function of
(mu, e). Pass: mu within `mu_tolerance` of the truth, and the truth inside the 95%
intervals of both parameters (an unidentifiable parameter's interval is the whole bound: it
cannot fail by being too narrow, and is reported as such).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from calibration.compare import case_like
from calibration.gns_objective import DESIGN_NAMES
from calibration.inverse import BOUNDS, inverse_design
from calibration.measured_column import MeasuredColumn, own_material_fields
from dem.case import Material
from dem.runout import RunoutMethod, runout_at
from dem.trajectory import Trajectory
from gns.dataset import read_training_attrs

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from gns.simulator import LearnedSimulator

log = logging.getLogger(__name__)


def recovery_targets(
    training_attrs: list[dict],
    n_cases: int,
    bounds: Sequence[Sequence[float]] = BOUNDS,
    seed: int = 0,
    min_distance: float = 0.05,
    margin: float = 0.1,
) -> np.ndarray:
    """[n_cases, 2] (mu, e) spread over the bounds (shrunk by `margin` of the range at each side, so
    the truth is not on a bound), each at least `min_distance` from every training case."""
    from scipy.stats import qmc

    bounds = np.asarray(bounds, float)
    low = bounds[:, 0] + margin * (bounds[:, 1] - bounds[:, 0])
    high = bounds[:, 1] - margin * (bounds[:, 1] - bounds[:, 0])
    trained = np.array([[float(a[n]) for n in DESIGN_NAMES] for a in training_attrs])
    sampler = qmc.LatinHypercube(d=2, seed=seed)
    chosen = []
    for _ in range(1000):
        point = low + sampler.random(1)[0] * (high - low)
        if np.min(np.linalg.norm(trained - point, axis=1)) >= min_distance:
            chosen.append(point)
            if len(chosen) == n_cases:
                return np.round(np.array(chosen), 4)
    raise ValueError(f"could not place {n_cases} targets {min_distance} away from the {len(trained)} training cases")


def packing_scatter(curves: Sequence[ArrayLike]) -> tuple[np.ndarray, int]:
    """Pooled std [K] of L* between packings and its degrees of freedom.

    curves: one [k_j, K] array per target (its k_j packings' L* at the same K t/t* points); each
    target's own mean is removed, so differences between targets do not count as scatter."""
    residuals = np.concatenate([np.asarray(c, float) - np.mean(c, axis=0) for c in curves])
    dof = len(residuals) - len(curves)
    if dof < 1:
        raise ValueError("packing scatter needs a target with at least two packings")
    return np.sqrt(np.sum(residuals**2, axis=0) / dof), dof


def synthetic_measured(
    truths: Trajectory | Iterable[Trajectory],
    t_points: ArrayLike,
    noise_std: float,
    seed: int,
    name: str,
    packing_std: ArrayLike | None = None,
    runout: RunoutMethod | None = None,
) -> MeasuredColumn:
    """The mean runout of DEM runs of one (mu, e) at t_points [K] (t/t*) plus Gaussian noise (std
    noise_std, L*).

    truths: a Trajectory or a list of k (one per packing). Its stated std is that of a mean of k
    packings with measurement noise: sqrt(noise_std^2 + packing_std^2 / k); packing_std [K] or
    scalar (L*), None: estimated from the truths themselves (which needs k >= 2). runout: how L*
    is read off the runs (None: dem.runout's default).
    """
    runout = RunoutMethod.from_config(runout)
    truths = [truths] if isinstance(truths, Trajectory) else list(truths)
    t_points = np.asarray(t_points, float)
    curves = np.array([runout_at(truth, t_points, runout) for truth in truths])
    if packing_std is None:
        if len(truths) < 2:
            raise ValueError(
                f"{name}: one packing tells nothing of the packing scatter; pass packing_std or "
                "use at least two packings"
            )
        packing_std = packing_scatter([curves])[0]
    packing_std = np.broadcast_to(np.asarray(packing_std, float), t_points.shape)
    noisy = curves.mean(axis=0) + np.random.default_rng(seed).normal(0.0, noise_std, len(t_points))
    a = truths[0].attrs
    return MeasuredColumn(
        name=name,
        material=str(a["material"]),
        aspect_ratio=float(a["aspect_ratio"]),
        L_i=float(a["L_i"]),
        t_over_tstar=t_points,
        runout=noisy,
        runout_std=np.sqrt(noise_std**2 + packing_std**2 / len(truths)),
        source=f"synthetic DEM runs ({name}: mean of {len(truths)} packings, noise {noise_std:g})",
        **own_material_fields(Material.from_attrs(a)),
    )


def recover_case(
    simulator: LearnedSimulator,
    metadata: dict,
    training_attrs: list[dict],
    start: Trajectory,
    truths: Trajectory | Iterable[Trajectory],
    t_points: ArrayLike,
    noise_std: float,
    seed: int,
    mu_tolerance: float = 0.03,
    packing_std: ArrayLike | None = None,
    runout: RunoutMethod | None = None,
    **inverse_kwargs: Any,
) -> dict:
    """Inverse design against one synthetic target; returns truth, estimate, intervals and verdicts.

    truths: the target's DEM runs (a Trajectory or a list, one per packing, same (mu, e));
    t_points: the target's t/t* points [K]; packing_std: the packing scatter of L* [K] (None: from
    the truths); it enters the target's stated std (as a mean of len(truths) packings) and the
    posterior's model side (the GNS rolls out one packing, `start`). runout: how L* is read, for
    the targets and the inverse design alike.
    """
    runout = RunoutMethod.from_config(runout)
    truths = [truths] if isinstance(truths, Trajectory) else list(truths)
    if packing_std is None:
        packing_std = (
            packing_scatter([[runout_at(t, t_points, runout) for t in truths]])[0] if len(truths) > 1 else None
        )
    measured = synthetic_measured(
        truths, t_points, noise_std, seed, name=f"target_{seed}", packing_std=packing_std, runout=runout
    )
    t0 = time.perf_counter()
    result = inverse_design(
        simulator,
        start,
        measured,
        metadata,
        training_attrs,
        start_packing_std=packing_std,
        runout=runout,
        **inverse_kwargs,
    )
    seconds = time.perf_counter() - t0
    truth_values = [float(truths[0].attrs[n]) for n in result.names]
    parameters = result.posterior["parameters"]
    inside = [p["low"] <= v <= p["high"] for p, v in zip(parameters, truth_values)]
    mu_error = abs(parameters[0]["value"] - truth_values[0])
    row = {
        "target": measured.name,
        "truth": truth_values,
        "estimate": [p["value"] for p in parameters],
        "interval": [[p["low"], p["high"]] for p in parameters],
        "identifiable": [p["identifiable"] for p in parameters],
        # each parameter's std scale the GNS's own chi^2 along its interval asked for (uncertainty.likelihood_checked)
        "interval_scale": (result.posterior.get("likelihood_check") or {}).get("scale"),
        "inside": inside,
        "mu_error": mu_error,
        "mu_within": bool(mu_error <= mu_tolerance),
        "objective": result.best_value,
        "start_objective": result.starts[0].iterates[0][1],
        "packings": len(truths),
        "packing_std": None if packing_std is None else np.broadcast_to(packing_std, measured.runout.shape).tolist(),
        "measured": measured.runout.tolist(),
        "measured_std": measured.runout_std.tolist(),
        "posterior_std": result.posterior["sigma"],  # [K] the noise the posterior used (inverse.noise_level)
        "t_over_tstar": measured.t_over_tstar.tolist(),
        "seconds": seconds,
        "online_s": result.seconds["online"],
        "n_batches": result.n_batches,
    }
    log.info(
        "%s: truth %s, estimate %s, mu error %.3f, inside %s",
        measured.name,
        truth_values,
        row["estimate"],
        mu_error,
        inside,
    )
    return row


def recovery_summary(rows: list[dict], mu_tolerance: float = 0.03) -> dict:
    """Counts and the issue's criteria: mu within tolerance, truth inside the 95% intervals in >= 4 of 5."""
    n = len(rows)
    within = sum(r["mu_within"] for r in rows)
    inside = sum(all(r["inside"]) for r in rows)
    return {
        "n_cases": n,
        "mu_tolerance": mu_tolerance,
        "mu_within": within,
        "truth_inside_95": inside,
        "mu_error_mean": float(np.mean([r["mu_error"] for r in rows])) if rows else float("nan"),
        "mu_error_max": float(np.max([r["mu_error"] for r in rows])) if rows else float("nan"),
        "passes": bool(n and within == n and inside >= int(np.ceil(0.8 * n))),
        "cases": rows,
    }


def plot_recovery(summary: dict, path: str | os.PathLike, title: str = "") -> None:
    """Truth against estimate with 95% intervals, for mu and e."""
    from dem.plots import plt, save_figure

    rows = summary["cases"]
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 4.2))
    for j, (ax, name) in enumerate(zip(axes, DESIGN_NAMES)):
        truth = np.array([r["truth"][j] for r in rows])
        estimate = np.array([r["estimate"][j] for r in rows])
        low = np.array([r["interval"][j][0] for r in rows])
        high = np.array([r["interval"][j][1] for r in rows])
        ok = np.array([r["inside"][j] for r in rows])
        ax.errorbar(truth, estimate, yerr=[estimate - low, high - estimate], fmt="none", ecolor="0.5", capsize=3)
        ax.scatter(truth[ok], estimate[ok], c="tab:blue", zorder=3, label="truth inside 95% interval")
        ax.scatter(truth[~ok], estimate[~ok], c="tab:red", zorder=3, label="truth outside")
        span = [min(truth.min(), low.min()) - 0.02, max(truth.max(), high.max()) + 0.02]
        ax.plot(span, span, "k:", lw=0.8)
        if j == 0:
            tol = summary["mu_tolerance"]
            ax.fill_between(span, np.array(span) - tol, np.array(span) + tol, color="0.85", label=f"+-{tol:g}")
        ax.set(xlabel=f"true {name}", ylabel=f"recovered {name}", title=name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(
        title
        or f"parameter recovery: mu within {summary['mu_tolerance']:g} in {summary['mu_within']} of "
        f"{summary['n_cases']}, truth inside 95% in {summary['truth_inside_95']}",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)


PAPER_TIMES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5)
TRUTH_SEED_OFFSET = 20_000  # packing seeds of the targets, far from the datasets' own
PACKING_SEED_STRIDE = 100  # target k's packings: seeds TRUTH_SEED_OFFSET + 100 k + j
# Packings averaged per target: benchmarks/recovery_feasibility.py finds the best reachable 95%
# half-width of mu at about 0.21/0.16/0.26/0.32 (mu ~ 0.375/0.525/0.675/0.825) from one packing and
# 0.12/0.10/0.17/0.19 from 4; more packings gain slowly (sqrt k) and cost a DEM run each.
PACKINGS_PER_TARGET = 4


def observation_times(duration_over_tstar: float, times: Sequence[float] = PAPER_TIMES) -> np.ndarray:
    """The paper's t/t* points that the dataset's simulated window covers (at least two)."""
    kept = np.array([t for t in times if t <= duration_over_tstar - 0.02])
    if len(kept) < 2:
        raise ValueError(f"a simulated window of {duration_over_tstar} t* holds fewer than two of {list(times)}")
    return kept


def recovery_study(
    simulator: LearnedSimulator,
    metadata: dict,
    n_cases: int = 5,
    noise_std: float = 0.05,
    model_error: Callable[[np.ndarray], np.ndarray] | None = None,
    seed: int = 0,
    mu_tolerance: float = 0.03,
    start: Sequence[float] | None = None,
    bounds: Sequence[Sequence[float] | None] | None = None,
    packings: int = PACKINGS_PER_TARGET,
    runout: RunoutMethod | None = None,
    dem_config: dict | None = None,
    **inverse_kwargs: Any,
) -> dict:
    """Recover n_cases synthetic DEM targets of the GNS dataset's own column, each the mean of
    `packings` DEM runs; returns the summary (recovery_summary plus dataset, t/t* points, noise,
    packing scatter and model error). model_error: the GNS's runout error (L*) [K] at t/t* points [K]
    (pipeline.inverse_design.model_error_from_evaluation; None: none joins the noise model). bounds:
    as calibration.inverse.design_bounds (None: the paper's, narrowed to the trained range). runout:
    how every L* is read (None: dem.runout's default); dem_config: the engine of the DEM runs (the
    workflow's `dem` section; None: builtin)."""
    from calibration.inverse import design_bounds
    from calibration.lbfgsb import PAPER_START
    from dem.engines import simulate_case

    if packings < 2:
        raise ValueError(f"packings = {packings}: the packing scatter needs at least two packings per target")
    trained = read_training_attrs(metadata)
    reference = trained[0]
    t_points = observation_times(float(reference.get("duration_over_tstar", 4.0)))
    model_error_std = None if model_error is None else np.asarray(model_error(t_points), float)
    start = start or PAPER_START
    bounds = design_bounds(bounds, list(DESIGN_NAMES), metadata["parameter_ranges"])
    log.info(
        "recovery on %s: %d targets of %d packings, t/t* %s, noise %.3g, GNS runout error %s",
        metadata["name"],
        n_cases,
        packings,
        t_points.tolist(),
        noise_std,
        None if model_error_std is None else np.round(model_error_std, 3).tolist(),
    )
    start_run = simulate_case(
        case_like(reference, *start, seed=TRUTH_SEED_OFFSET - 1, name="recovery_start"), dem_config
    )
    targets = recovery_targets(trained, n_cases, bounds, seed)
    truths = []
    for k, (mu, e) in enumerate(targets):
        truths.append(
            [
                simulate_case(
                    case_like(
                        reference,
                        float(mu),
                        float(e),
                        seed=TRUTH_SEED_OFFSET + PACKING_SEED_STRIDE * k + j,
                        name=f"target_{k}_packing_{j}",
                    ),
                    dem_config,
                )
                for j in range(packings)
            ]
        )
        log.info("target %d/%d: %d DEM packings run", k + 1, n_cases, packings)
    runout = RunoutMethod.from_config(runout)
    packing_std, packing_dof = packing_scatter([[runout_at(t, t_points, runout) for t in group] for group in truths])
    log.info("packing scatter of L* (pooled, %d dof): %s", packing_dof, np.round(packing_std, 3).tolist())
    rows = []
    for k, group in enumerate(truths):
        rows.append(
            recover_case(
                simulator,
                metadata,
                trained,
                start_run,
                group,
                t_points,
                noise_std,
                seed + k,
                mu_tolerance,
                packing_std=packing_std,
                bounds=bounds,
                first_start=start,
                model_error_std=model_error_std,
                runout=runout,
                **inverse_kwargs,
            )
        )
        log.info("target %d/%d done", k + 1, n_cases)
    summary = recovery_summary(rows, mu_tolerance)
    summary.update(
        dataset=metadata["name"],
        t_over_tstar=t_points.tolist(),
        noise_std=noise_std,
        packings=packings,
        packing_std=packing_std.tolist(),
        packing_dof=packing_dof,
        model_error_std=None if model_error_std is None else model_error_std.tolist(),
        bounds=[list(b) for b in bounds],
        runout=runout.to_config(),
    )
    return summary
