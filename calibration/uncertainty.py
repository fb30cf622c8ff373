"""Uncertainty of calibrated parameters: a Laplace (Gauss-Newton) posterior under a stated noise model.

Noise model: each measured L*_k = model_k(theta) + eps_k, eps_k ~ N(0, sigma_k^2) independent, flat
prior within the bounds. Near the optimum the model is linearised, model(theta) ~ model(theta*) +
J (theta - theta*), so the posterior is Gaussian with covariance (J^T W J)^-1, W = diag(1/sigma_k^2).
When the measured data carry no noise level, sigma is estimated from the residuals at the optimum,
sigma^2 = SSE / (K - p) (and said so).

A parameter the data cannot pin down (its 95% interval is wider than the bounds, or the data hardly
move with it) is flagged `identifiable = False`: its optimum is then a guess, not a measurement.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

Z95 = 1.959963984540054


@dataclass
class ParameterInterval:
    name: str
    value: float  # optimum
    std: float  # posterior standard deviation
    low: float  # 95% credible interval, clipped to the bounds
    high: float
    identifiable: bool
    why: str  # plain words when not identifiable


@dataclass
class LaplacePosterior:
    parameters: list[ParameterInterval]
    covariance: np.ndarray  # [p, p]
    correlation: np.ndarray  # [p, p]
    sigma: np.ndarray  # [K] noise std used
    sigma_source: str  # "measured" or "estimated from residuals"

    def to_dict(self) -> dict:
        return {
            "parameters": [asdict(p) for p in self.parameters],
            "covariance": self.covariance.tolist(),
            "correlation": self.correlation.tolist(),
            "sigma": self.sigma.tolist(),
            "sigma_source": self.sigma_source,
        }

    @classmethod
    def from_dict(cls, data: dict) -> LaplacePosterior:
        """Inverse of `to_dict` (as read back from JSON)."""
        return cls(
            [ParameterInterval(**p) for p in data["parameters"]],
            np.asarray(data["covariance"], float),
            np.asarray(data["correlation"], float),
            np.asarray(data["sigma"], float),
            data["sigma_source"],
        )


def laplace_posterior(
    names: Sequence[str],
    optimum: ArrayLike,
    jacobian: ArrayLike,
    residuals: ArrayLike,
    bounds: Sequence[tuple[float, float]],
    sigma: ArrayLike | float | None = None,
    untrusted: Mapping[str, str] | None = None,
) -> LaplacePosterior:
    """Gaussian posterior around `optimum` [p].

    jacobian [K, p]: d(simulated L*_k)/d(theta_j) at the optimum; residuals [K] = simulated - measured;
    bounds [(low, high)] * p; sigma: [K] or scalar measured noise std, or None to estimate it.
    untrusted: {name: why} of parameters whose slope is no evidence (a surrogate's response that the
    simulator it stands for does not show): their columns are left out as an unknown slope's are, so
    their intervals are their bounds and the others' do not lean on them; `why` says so.
    """
    jacobian = np.atleast_2d(np.asarray(jacobian, float))
    residuals = np.asarray(residuals, float)
    optimum = np.asarray(optimum, float)
    n_points, n_params = jacobian.shape
    if residuals.shape != (n_points,) or optimum.shape != (n_params,) or len(names) != n_params:
        raise ValueError(
            f"shapes disagree: jacobian {jacobian.shape}, residuals {residuals.shape}, "
            f"optimum {optimum.shape}, names {len(names)}"
        )
    if not np.all(np.isfinite(residuals)):
        raise ValueError("non-finite residuals at the optimum: no posterior")
    # a parameter whose slope could not be formed (the model failed both sides of the optimum):
    # its column is zeroed, so the ridge below gives it a huge variance, and it is flagged
    unknown = ~np.all(np.isfinite(jacobian), axis=0)
    untrusted = dict(untrusted or {})
    left_out = unknown | np.array([name in untrusted for name in names])
    jacobian = np.where(left_out[None, :], 0.0, jacobian)
    if sigma is None:
        dof = max(n_points - n_params, 1)
        sigma = np.full(n_points, max(np.sqrt(np.sum(residuals**2) / dof), 1e-12))
        source = f"estimated from residuals (SSE / (K - p), K = {n_points}, p = {n_params})"
    else:
        sigma = np.broadcast_to(np.asarray(sigma, float), (n_points,)).copy()
        if np.any(sigma <= 0):
            raise ValueError("noise level must be positive")
        source = "measured"
    weighted = jacobian / sigma[:, None]
    fisher = weighted.T @ weighted
    # a tiny ridge instead of a pseudo-inverse: a direction the data cannot see must come out
    # with a huge variance, not the zero variance a pseudo-inverse would give it
    ridge = 1e-12 * max(np.trace(fisher), 1e-300)
    covariance = np.linalg.inv(fisher + ridge * np.eye(n_params))
    std = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    correlation = covariance / np.outer(std, std)
    parameters = []
    for j, name in enumerate(names):
        low_bound, high_bound = bounds[j]
        width = high_bound - low_bound
        half = Z95 * std[j]
        why = ""
        if unknown[j]:
            why = "the model failed a Jacobian step either side of the optimum: its slope is unknown"
        elif name in untrusted:
            why = untrusted[name]
        elif 2 * half > width:
            why = (
                f"its 95% interval ({2 * half:.3g} wide) is wider than the bounds ({width:.3g}): "
                "the measured runout hardly changes with it"
            )
        parameters.append(
            ParameterInterval(
                name=name,
                value=float(optimum[j]),
                std=float(std[j]),
                low=float(max(low_bound, optimum[j] - half)),
                high=float(min(high_bound, optimum[j] + half)),
                identifiable=not why,
                why=why,
            )
        )
    return LaplacePosterior(parameters, covariance, correlation, sigma, source)


def finite_difference_jacobian(
    model: Callable[[np.ndarray], ArrayLike],
    theta: ArrayLike,
    bounds: Sequence[tuple[float, float]],
    step: float | ArrayLike = 1e-2,
    centre: ArrayLike | None = None,
) -> np.ndarray:
    """[K, p] central differences of model(theta) -> [K], steps (a scalar or one per parameter [p])
    kept inside the bounds.

    centre: model(theta) [K], when known. Then a side where the model gives a non-finite value (a
    surrogate's rollout that failed) falls back to the one-sided difference from the centre, and a
    column whose two sides both fail is NaN (laplace_posterior flags that parameter)."""
    theta = np.asarray(theta, float)
    steps = np.broadcast_to(np.asarray(step, float), theta.shape)
    columns = []
    for j in range(len(theta)):
        low, high = bounds[j]
        up, down = theta.copy(), theta.copy()
        up[j] = min(theta[j] + steps[j], high)
        down[j] = max(theta[j] - steps[j], low)
        above, below = np.asarray(model(up), float), np.asarray(model(down), float)
        if centre is not None and not np.all(np.isfinite(above)):
            above, up = np.asarray(centre, float), theta
        if centre is not None and not np.all(np.isfinite(below)):
            below, down = np.asarray(centre, float), theta
        span = up[j] - down[j]
        columns.append((above - below) / span if span > 0 else np.full(above.shape, np.nan))
    return np.stack(columns, axis=1)
