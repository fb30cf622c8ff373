"""Bayesian optimisation directly on DEM runs: what an engineer would pick instead of a surrogate.

A Gaussian process (Matern 5/2 + white noise, scikit-learn) models the objective over the bounded
parameter box; each new run goes where the expected improvement is largest. The budget counts
every objective call (the initial Latin-hypercube design included).
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize
from scipy.stats import norm, qmc
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

log = logging.getLogger(__name__)


@dataclass
class OptimisationHistory:
    """Every evaluation in order: params [n, p], values [n], wall time of each call (s)."""

    names: list
    params: list = field(default_factory=list)
    values: list = field(default_factory=list)
    seconds: list = field(default_factory=list)

    def record(self, params, value, seconds):
        self.params.append([float(p) for p in params])
        self.values.append(float(value))
        self.seconds.append(float(seconds))

    @property
    def best(self) -> tuple[np.ndarray, float]:
        k = int(np.argmin(self.values))
        return np.array(self.params[k]), self.values[k]

    def to_dict(self) -> dict:
        best_params, best_value = self.best
        return {
            "names": list(self.names),
            "params": self.params,
            "values": self.values,
            "seconds": self.seconds,
            "best_params": best_params.tolist(),
            "best_value": best_value,
        }


def expected_improvement(mean, std, best):
    """EI for minimisation; mean, std [n] of the GP at candidate points."""
    std = np.maximum(std, 1e-12)
    z = (best - mean) / std
    return (best - mean) * norm.cdf(z) + std * norm.pdf(z)


def bayesian_optimisation(
    objective, bounds, names, budget: int = 20, n_initial: int = 6, seed: int = 0, progress=None
) -> OptimisationHistory:
    """Minimise objective(params [p]) -> float within bounds [(low, high)] * p in `budget` calls."""
    if budget < n_initial or n_initial < 2:
        raise ValueError(f"budget ({budget}) must be at least n_initial ({n_initial}) >= 2")
    bounds = np.asarray(bounds, float)
    low, high = bounds[:, 0], bounds[:, 1]
    rng = np.random.default_rng(seed)
    history = OptimisationHistory(names=list(names))

    def call(params):
        t0 = time.perf_counter()
        value = float(objective(params))
        if not np.isfinite(value):
            raise ValueError(f"objective is not finite at {dict(zip(names, params))}")
        history.record(params, value, time.perf_counter() - t0)
        log.info(
            "run %d/%d: %s -> %.4g",
            len(history.values),
            budget,
            ", ".join(f"{n}={p:.3f}" for n, p in zip(names, params)),
            value,
        )
        if progress is not None:
            progress(len(history.values) / budget)

    unit = qmc.LatinHypercube(d=len(low), seed=seed).random(n_initial)
    for point in low + unit * (high - low):
        call(point)
    kernel = ConstantKernel(1.0) * Matern(length_scale=np.full(len(low), 0.3), nu=2.5) + WhiteKernel(1e-4)
    while len(history.values) < budget:
        x = (np.array(history.params) - low) / (high - low)
        y = np.array(history.values)
        y_scaled = (y - y.mean()) / (y.std() + 1e-12)
        gp = GaussianProcessRegressor(kernel, normalize_y=False, random_state=seed, n_restarts_optimizer=2)
        with warnings.catch_warnings():  # hyper-parameters at their bounds are fine here
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp.fit(x, y_scaled)
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
        if np.min(np.linalg.norm(x - u, axis=1)) < 1e-3:  # do not pay for a run already made
            u = candidates[np.argmax(expected_improvement(mean, std, best))]
        call(low + u * (high - low))
    return history
