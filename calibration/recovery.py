"""Parameter recovery on synthetic targets: DEM runs with known (mu, e), not in the GNS's training
set, serve as "measured" curves with noise; the GNS inverse design must find mu again.

Each target is a builtin-DEM run of the GNS dataset's own column (same material, geometry, grain
size and frame interval) with its own packing seed; its runout at the chosen t/t* points plus
Gaussian noise of known std is the measurement. The inverse design starts every rollout from the
first frames of a reference run at the paper's start point (another packing, as a real
measurement would have), so packing-to-packing scatter is part of what it must live with.
Pass: mu within `mu_tolerance` of the truth, and the truth inside the 95% intervals of both
parameters (an unidentifiable parameter's interval is the whole bound: it cannot fail by being
too narrow, and is reported as such).
"""
from __future__ import annotations

import json
import logging
import time

import numpy as np

from calibration.compare import case_like, read_training_attrs
from calibration.inverse import BOUNDS, DESIGN_NAMES, inverse_design
from calibration.measured import MeasuredColumn
from dem.runout import runout_at
from dem.trajectory import Trajectory

log = logging.getLogger(__name__)
def recovery_targets(training_attrs: list[dict], n_cases: int, bounds=BOUNDS, seed: int = 0,
                     min_distance: float = 0.05, margin: float = 0.1) -> np.ndarray:
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


def synthetic_measured(truth: Trajectory, t_points, noise_std: float, seed: int, name: str) -> MeasuredColumn:
    """The runout of a DEM run at t_points with Gaussian noise (std noise_std, stated in the data)."""
    t_points = np.asarray(t_points, float)
    clean = runout_at(truth, t_points)
    noisy = clean + np.random.default_rng(seed).normal(0.0, noise_std, len(t_points))
    a = truth.attrs
    return MeasuredColumn(name=name, material=str(a["material"]), aspect_ratio=float(a["aspect_ratio"]),
                          L_i=float(a["L_i"]), t_over_tstar=t_points, runout=noisy,
                          runout_std=np.full(len(t_points), noise_std), source=f"synthetic DEM run ({name})")


def recover_case(simulator, metadata, training_attrs, start: Trajectory, truth: Trajectory, t_points,
                 noise_std: float, seed: int, mu_tolerance: float = 0.03, **inverse_kwargs) -> dict:
    """Inverse design against one synthetic target; returns truth, estimate, intervals and verdicts."""
    measured = synthetic_measured(truth, t_points, noise_std, seed, name=f"target_{seed}")
    t0 = time.perf_counter()
    result = inverse_design(simulator, start, measured, metadata, training_attrs, **inverse_kwargs)
    seconds = time.perf_counter() - t0
    truth_values = [float(truth.attrs[n]) for n in result.names]
    parameters = result.posterior["parameters"]
    inside = [p["low"] <= v <= p["high"] for p, v in zip(parameters, truth_values)]
    mu_error = abs(parameters[0]["value"] - truth_values[0])
    row = {"target": measured.name, "truth": truth_values, "estimate": [p["value"] for p in parameters],
           "interval": [[p["low"], p["high"]] for p in parameters],
           "identifiable": [p["identifiable"] for p in parameters], "inside": inside,
           "mu_error": mu_error, "mu_within": bool(mu_error <= mu_tolerance), "objective": result.best_value,
           "start_objective": result.starts[0].iterates[0][1],
           "measured": measured.runout.tolist(), "t_over_tstar": measured.t_over_tstar.tolist(),
           "seconds": seconds, "online_s": result.seconds["online"], "n_batches": result.n_batches}
    log.info("%s: truth %s, estimate %s, mu error %.3f, inside %s", measured.name, truth_values, row["estimate"],
             mu_error, inside)
    return row


def recovery_summary(rows: list[dict], mu_tolerance: float = 0.03) -> dict:
    """Counts and the issue's criteria: mu within tolerance, truth inside the 95% intervals in >= 4 of 5."""
    n = len(rows)
    within = sum(r["mu_within"] for r in rows)
    inside = sum(all(r["inside"]) for r in rows)
    return {"n_cases": n, "mu_tolerance": mu_tolerance, "mu_within": within, "truth_inside_95": inside,
            "mu_error_mean": float(np.mean([r["mu_error"] for r in rows])) if rows else float("nan"),
            "mu_error_max": float(np.max([r["mu_error"] for r in rows])) if rows else float("nan"),
            "passes": bool(n and within == n and inside >= int(np.ceil(0.8 * n))), "cases": rows}


def plot_recovery(summary: dict, path, title: str = "") -> None:
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
    fig.suptitle(title or f"parameter recovery: mu within {summary['mu_tolerance']:g} in {summary['mu_within']} of "
                 f"{summary['n_cases']}, truth inside 95% in {summary['truth_inside_95']}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


PAPER_TIMES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5)
TRUTH_SEED_OFFSET = 20_000      # packing seeds of the targets, far from the datasets' own


def observation_times(duration_over_tstar: float, times=PAPER_TIMES) -> np.ndarray:
    """The paper's t/t* points that the dataset's simulated window covers (at least two)."""
    kept = np.array([t for t in times if t <= duration_over_tstar - 0.02])
    if len(kept) < 2:
        raise ValueError(f"a simulated window of {duration_over_tstar} t* holds fewer than two of {list(times)}")
    return kept


def recovery_study(simulator, metadata, n_cases: int = 5, noise_std: float = 0.05, model_error_std=None,
                   seed: int = 0, mu_tolerance: float = 0.03, start=None, bounds=None, **inverse_kwargs) -> dict:
    """Recover n_cases synthetic DEM targets of the GNS dataset's own column; returns the summary
    (recovery_summary plus dataset, t/t* points, noise and model error). bounds: as
    calibration.inverse.design_bounds (None: the paper's, narrowed to the trained range)."""
    from calibration.inverse import PAPER_START, design_bounds
    from dem.collapse import simulate_collapse

    trained = read_training_attrs(metadata)
    reference = trained[0]
    t_points = observation_times(float(reference.get("duration_over_tstar", 4.0)))
    start = start or PAPER_START
    bounds = design_bounds(bounds, list(DESIGN_NAMES), metadata["parameter_ranges"])
    log.info("recovery on %s: %d targets, t/t* %s, noise %.3g, GNS runout error %s", metadata["name"], n_cases,
             t_points.tolist(), noise_std, model_error_std)
    start_run = simulate_collapse(case_like(reference, *start, seed=TRUTH_SEED_OFFSET - 1, name="recovery_start"))
    rows = []
    for k, (mu, e) in enumerate(recovery_targets(trained, n_cases, bounds, seed)):
        truth = simulate_collapse(case_like(reference, float(mu), float(e), seed=TRUTH_SEED_OFFSET + k,
                                            name=f"target_{k}"))
        rows.append(recover_case(simulator, metadata, trained, start_run, truth, t_points, noise_std, seed + k,
                                 mu_tolerance, bounds=bounds, first_start=start, model_error_std=model_error_std,
                                 **inverse_kwargs))
        log.info("target %d/%d done", k + 1, n_cases)
    summary = recovery_summary(rows, mu_tolerance)
    summary.update(dataset=metadata["name"], t_over_tstar=t_points.tolist(), noise_std=noise_std,
                   model_error_std=model_error_std, bounds=[list(b) for b in bounds])
    return summary


def run_recovery(model_path, metadata_path, out_json, out_figure, evaluation_path=None, **study_kwargs) -> dict:
    """The recovery stage: recovery_study with the GNS at model_path; writes JSON and figure."""
    from calibration.inverse import model_error_from_evaluation
    from dem.atomic import write_text
    from gns.data import read_metadata
    from gns.simulator import load_simulator

    metadata = read_metadata(metadata_path)
    summary = recovery_study(load_simulator(model_path, metadata), metadata,
                             model_error_std=model_error_from_evaluation(evaluation_path), **study_kwargs)
    write_text(out_json, json.dumps(summary, indent=1) + "\n")
    plot_recovery(summary, out_figure, title=f"{metadata['name']}: mu within {summary['mu_tolerance']:g} in "
                  f"{summary['mu_within']} of {summary['n_cases']}, truth inside 95% in {summary['truth_inside_95']}")
    return summary
