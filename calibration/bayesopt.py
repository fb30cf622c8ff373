"""Bayesian optimisation directly on DEM runs: what an engineer would pick instead of a surrogate.

A Gaussian process (calibration.gp: Matern 5/2 + white noise) models the objective over the
bounded parameter box; each new run goes where the expected improvement is largest. The budget
counts every objective call (the initial Latin-hypercube design included). The call and its result
are those of every optimiser here (calibration.optimise).

A point whose objective raises PointFailed (its DEM run failed) is recorded with its reason in the
history's `failed` list and counts against the budget; the GP never sees it, and no later point is
placed on it. Until two points have values, the next point is drawn at random instead of by
expected improvement. No point evaluated at all: OptimisationError with every reason.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.stats import norm, qmc

from calibration.gp import fit_gp
from calibration.optimise import BatchObjective, OptimisationHistory, OptimisationResult, PointFailed, Progress

log = logging.getLogger(__name__)


@dataclass
class BOSettings:
    """budget: objective calls in all, the initial design included; n_initial: points of the initial
    Latin-hypercube design; seed: of the design, the GP's restarts and the candidate points."""

    budget: int = 20
    n_initial: int = 6
    seed: int = 0


def expected_improvement(mean: np.ndarray, std: np.ndarray, best: float) -> np.ndarray:
    """[n] EI for minimisation; mean, std [n] of the GP at candidate points, best: lowest value so far."""
    std = np.maximum(std, 1e-12)
    z = (best - mean) / std
    return (best - mean) * norm.cdf(z) + std * norm.pdf(z)


def bayesian_optimisation(
    objective: BatchObjective,
    bounds: Sequence[Sequence[float]],
    names: Sequence[str],
    settings: BOSettings | None = None,
    progress: Progress | None = None,
) -> OptimisationResult:
    """Minimise objective(points [1, p]) -> values [1] within bounds [(low, high)] * p in
    settings.budget calls of one point each (the calibration.optimise.Optimiser call).

    Every evaluation is start 0; its iteration is 0 for the initial design, k for the k-th point
    chosen by expected improvement. progress(call number, seconds, values [1]) after each call.
    """
    settings = settings or BOSettings()
    budget, n_initial, seed = settings.budget, settings.n_initial, settings.seed
    if budget < n_initial or n_initial < 2:
        raise ValueError(f"budget ({budget}) must be at least n_initial ({n_initial}) >= 2")
    bounds = np.asarray(bounds, float)
    low, high = bounds[:, 0], bounds[:, 1]
    rng = np.random.default_rng(seed)
    history = OptimisationHistory(names=list(names))

    def call(params, iteration):
        t0 = time.perf_counter()
        try:
            value = float(np.asarray(objective(np.atleast_2d(params)), float)[0])
        except PointFailed as exc:  # recorded with its reason; the GP never sees it
            seconds = time.perf_counter() - t0
            history.record_failure(params, str(exc), seconds, start=0, iteration=iteration)
            log.warning("run %d/%d at %s failed, left out: %s", history.n_calls, budget, point_text(params), exc)
            if progress is not None:
                progress(history.n_calls, seconds, np.array([np.nan]))
            return
        seconds = time.perf_counter() - t0
        if not np.isfinite(value):
            raise ValueError(f"objective is not finite at {dict(zip(names, params))}")
        history.record(params, value, seconds, start=0, iteration=iteration)
        log.info("run %d/%d: %s -> %.4g", history.n_calls, budget, point_text(params), value)
        if progress is not None:
            progress(history.n_calls, seconds, np.array([value]))

    def point_text(params):
        return ", ".join(f"{n}={p:.3f}" for n, p in zip(names, params))

    unit = qmc.LatinHypercube(d=len(low), seed=seed).random(n_initial)
    for point in low + unit * (high - low):
        call(point, 0)
    while history.n_calls < budget:
        iteration = history.n_calls - n_initial + 1
        if len(history.values) < 2:  # too few values for a GP: explore at random
            call(low + rng.uniform(size=len(low)) * (high - low), iteration)
            continue
        x = (np.array(history.params) - low) / (high - low)
        y = np.array(history.values)
        y_scaled = (y - y.mean()) / (y.std() + 1e-12)
        gp = fit_gp(x, y_scaled, 1.0, np.full(len(low), 0.3), 1e-4, n_restarts=2, seed=seed)
        best = y_scaled.min()

        # negative_ei is only called by minimize() below, within this iteration, so it sees this gp and best.
        def negative_ei(u):
            mean, std = gp.predict(np.atleast_2d(u), return_std=True)  # noqa: B023
            return -expected_improvement(mean, std, best)[0]  # noqa: B023

        candidates = rng.uniform(size=(512, len(low)))
        mean, std = gp.predict(candidates, return_std=True)
        starts = candidates[np.argsort(-expected_improvement(mean, std, best))[:4]]
        polished = [minimize(negative_ei, s, bounds=[(0, 1)] * len(low), method="L-BFGS-B") for s in starts]
        u = min(polished, key=lambda r: r.fun).x
        tried = np.vstack([x] + [(np.array(f["params"]) - low) / (high - low) for f in history.failed])
        if np.min(np.linalg.norm(tried - u, axis=1)) < 1e-3:  # do not pay again for a run made or failed
            u = candidates[np.argmax(expected_improvement(mean, std, best))]
        call(low + u * (high - low), iteration)
    params, value = history.best  # none evaluated: OptimisationError with every failure
    return OptimisationResult(params=params.tolist(), value=value, history=history, n_batches=history.n_calls)
