"""Uncertainty of calibrated parameters: a Laplace (Gauss-Newton) posterior under a stated noise model.

Noise model: each measured L*_k = model_k(theta) + eps_k, eps_k ~ N(0, sigma_k^2) independent, flat
prior within the bounds. Near the optimum the model is linearised, model(theta) ~ model(theta*) +
J (theta - theta*), so the posterior is Gaussian with covariance (J^T W J)^-1, W = diag(1/sigma_k^2).
When the measured data carry no noise level, sigma is estimated from the residuals at the optimum,
sigma^2 = SSE / (K - p) (and said so).

A parameter the data cannot pin down (its 95% interval is wider than the bounds, or the data hardly
move with it) is flagged `identifiable = False`: its optimum is then a guess, not a measurement,
and its interval is the whole bounds.

The linearisation trusts the slope at the optimum. A rollout of a chaotic collapse is rough: its
slope over a Jacobian step can be several times its trend, and its chi^2 can come back down beyond
a bump, so a Laplace interval can exclude values the model itself fits within the noise
(measured on the tiny recovery test: 3 of 7 GNS trainings). `likelihood_checked` probes the
model's own chi^2 along each interval out to the bounds and widens an interval to where it truly
rises by Z95^2 (never narrows one).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

log = logging.getLogger(__name__)

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
    # the model's own chi^2 along the intervals against the linearised one, and the std scale that
    # check applied to each parameter (likelihood_checked); None: not checked
    likelihood_check: dict | None = None

    def to_dict(self) -> dict:
        return {
            "parameters": [asdict(p) for p in self.parameters],
            "covariance": self.covariance.tolist(),
            "correlation": self.correlation.tolist(),
            "sigma": self.sigma.tolist(),
            "sigma_source": self.sigma_source,
            "likelihood_check": self.likelihood_check,
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
            data.get("likelihood_check"),
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
    whys = [
        "the model failed a Jacobian step either side of the optimum: its slope is unknown"
        if unknown[j]
        else untrusted.get(name, "")
        for j, name in enumerate(names)
    ]
    parameters = intervals(names, optimum, std, bounds, whys)
    return LaplacePosterior(parameters, covariance, correlation, sigma, source)


def intervals(
    names: Sequence[str],
    optimum: np.ndarray,
    std: np.ndarray,
    bounds: Sequence[tuple[float, float]],
    whys: Sequence[str],
) -> list[ParameterInterval]:
    """95% intervals optimum +- Z95 std [p], clipped to the bounds, and the whole bounds for a
    parameter not identifiable (its optimum is a guess: no side of the range is ruled out); whys
    [p]: why a parameter is not identifiable whatever its std ("" where its std decides: an
    interval wider than the bounds)."""
    parameters = []
    for j, name in enumerate(names):
        low_bound, high_bound = bounds[j]
        width = high_bound - low_bound
        half = Z95 * std[j]
        why = whys[j]
        # wider than the bounds, or (an optimum near the middle) reaching both of them: nothing ruled out
        if not why and (2 * half > width or (optimum[j] - half <= low_bound and optimum[j] + half >= high_bound)):
            why = (
                f"its 95% interval ({2 * half:.3g} wide) is wider than the bounds ({width:.3g}): "
                "the measured runout hardly changes with it"
            )
        parameters.append(
            ParameterInterval(
                name=name,
                value=float(optimum[j]),
                std=float(std[j]),
                low=float(low_bound if why else max(low_bound, optimum[j] - half)),
                high=float(high_bound if why else min(high_bound, optimum[j] + half)),
                identifiable=not why,
                why=why,
            )
        )
    return parameters


# A Laplace interval rests on the slope at the optimum. On a rough or curved response (a chaotic
# rollout) that slope can be far steeper than the trend, or the objective can come down again
# beyond a bump, and the interval is then far too narrow for the model's own likelihood.
MIN_END_STEP = 0.05  # an end this close to the optimum (a fraction of its way) sits at a bound: not probed
NEAR_END = (1.0, 1.5)  # probes at these multiples of each end's step, to place a crossing near it
FAR_PROBES = 4  # and this many evenly spaced from there to the bound, to catch a valley beyond a bump


def interval_ends(
    posterior: LaplacePosterior, bounds: Sequence[tuple[float, float]]
) -> list[tuple[int, np.ndarray, float]]:
    """Each identifiable parameter's two interval ends as steps from the optimum along the posterior's
    own direction, +- Z95 C[:, j] / sqrt(C_jj) over the identifiable parameters (where the linearised
    chi^2 rises by Z95^2 at a whole step), or along its own axis where the bounds block that.
    Returns [(parameter index, step [p], the most multiple of the step the bounds allow)]; an end
    the bounds leave less than MIN_END_STEP of its way is left out."""
    optimum = np.array([p.value for p in posterior.parameters])
    low, high = np.asarray(bounds, float).T
    known = np.array([p.identifiable for p in posterior.parameters])
    ends = []

    def room(step):  # the most multiple of step that stays inside the bounds
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(
                np.where(step > 0, (high - optimum) / step, np.where(step < 0, (low - optimum) / step, np.inf)).min()
            )

    for j in np.flatnonzero(known):
        direction = np.where(known, Z95 * posterior.covariance[:, j] / np.sqrt(posterior.covariance[j, j]), 0.0)
        axis = np.where(np.arange(len(optimum)) == j, Z95 * np.sqrt(posterior.covariance[j, j]), 0.0)
        for sign in (1.0, -1.0):
            # at a corner the joint direction leaves the box at once through another parameter's
            # bound: then along this parameter alone (where the linearised rise is at least Z95^2)
            for step in (sign * direction, sign * axis):
                most = room(step)
                if most >= MIN_END_STEP:
                    ends.append((int(j), step, most))
                    break
    return ends


def end_multiples(most: float) -> np.ndarray:
    """Multiples of an end's step to probe [n], ascending, the last at the bound (`most`)."""
    far = 1.5 + (most - 1.5) * np.arange(1, FAR_PROBES + 1) / FAR_PROBES if most > 1.5 else []
    return np.unique(np.minimum(np.concatenate([NEAR_END, far]), most))


def crossing(multiples: np.ndarray, rise: np.ndarray) -> float:
    """The multiple where the chi^2 rise [n] at multiples [n] (ascending) last crosses Z95^2 going out:
    beyond the farthest probe still below it, interpolated in sqrt(rise), which is linear in the step
    for a linear model; the bound's multiple where even that probe is below; 1 (the Laplace end
    kept) where every probe is above. A failed probe (NaN) counts as above."""
    below = np.flatnonzero(np.nan_to_num(rise, nan=np.inf) < Z95**2)
    if not len(below):
        return 1.0
    i = below[-1]
    if i == len(multiples) - 1:
        return float(multiples[i])
    inner, outer = np.sqrt(max(rise[i], 0.0)), np.sqrt(rise[i + 1]) if np.isfinite(rise[i + 1]) else np.inf
    if not np.isfinite(outer):
        return float(multiples[i + 1])
    return float(multiples[i] + (multiples[i + 1] - multiples[i]) * (Z95 - inner) / (outer - inner))


def widened(posterior: LaplacePosterior, scale: ArrayLike, bounds: Sequence[tuple[float, float]]) -> LaplacePosterior:
    """The posterior with each parameter's std x scale [p] (>= 1; the covariance D C D, D = diag(scale),
    so the correlations keep), identifiability judged again; a parameter not identifiable for a reason
    of its own stays so."""
    scale = np.broadcast_to(np.asarray(scale, float), (len(posterior.parameters),))
    covariance = posterior.covariance * np.outer(scale, scale)
    std = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    names = [p.name for p in posterior.parameters]
    optimum = np.array([p.value for p in posterior.parameters])
    own = [p.why if p.why and "wider than the bounds" not in p.why else "" for p in posterior.parameters]
    return LaplacePosterior(
        intervals(names, optimum, std, bounds, own),
        covariance,
        posterior.correlation,
        posterior.sigma,
        posterior.sigma_source,
        posterior.likelihood_check,
    )


def likelihood_checked(
    runout_of: Callable[[np.ndarray], np.ndarray],
    measured: ArrayLike,
    posterior: LaplacePosterior,
    bounds: Sequence[Sequence[float]],
) -> LaplacePosterior:
    """The Laplace posterior held to the model's own likelihood (runout_of: points [G, P] -> L* [G, K],
    NaN where a rollout failed; measured: L* [K]). Along each identifiable parameter's interval
    directions (interval_ends) the model's chi^2 under the posterior's noise is probed, in one call,
    near the end and on to the bound; where it stays below the optimum's + Z95^2 farther out than
    the linearisation says (a slope steeper than the trend, or a valley beyond a bump), that
    parameter's std is scaled by the farther of its two crossings (`crossing`), so no interval is
    narrower than the model's own 95% likelihood ratio along it. One that rises faster is kept:
    that interval is conservative. The probes (points, rises, crossings) and each parameter's
    scale go into posterior.likelihood_check."""
    measured = np.asarray(measured, float)
    sigma = np.asarray(posterior.sigma, float)
    optimum = np.array([p.value for p in posterior.parameters])
    ends = interval_ends(posterior, bounds)
    multiples = [end_multiples(most) for _, _, most in ends]
    points = [optimum[None] + m[:, None] * step[None] for (_, step, _), m in zip(ends, multiples)]
    every = np.vstack([optimum[None]] + points)
    chi2 = np.sum(np.square((runout_of(every) - measured) / sigma), axis=1)  # NaN where a rollout failed
    rises = np.split(chi2[1:] - chi2[0], np.cumsum([len(m) for m in multiples])[:-1]) if ends else []
    crossings = [crossing(m, r) for m, r in zip(multiples, rises)]
    scale = np.ones(len(optimum))
    unbounded = {j: True for j, _, _ in ends}  # whether every probed side stays below out to its bound
    for (j, _, most), c in zip(ends, crossings):
        scale[j] = max(scale[j], c)
        unbounded[j] &= c >= most
    record = {
        "chi2_at_optimum": float(chi2[0]) if np.isfinite(chi2[0]) else None,  # None: its rollout failed
        "scale": scale.tolist(),
        "ends": [
            {
                "parameter": posterior.parameters[j].name,
                "points": p.tolist(),
                "multiples": m.tolist(),
                "rise": [float(r) if np.isfinite(r) else None for r in rise],
                "crossing": c,
            }
            for (j, _, _), p, m, rise, c in zip(ends, points, multiples, rises, crossings)
        ],
    }
    if np.any(scale > 1.0):
        log.info("posterior: std x %s to meet the model's own chi^2 along the intervals", np.round(scale, 3).tolist())
        posterior = widened(posterior, scale, bounds)
    flat = "the model's chi^2 stays within Z95^2 of the optimum's out to the bounds: the runout hardly changes with it"
    parameters = [
        replace(p, low=bounds[j][0], high=bounds[j][1], identifiable=False, why=flat) if unbounded.get(j) else p
        for j, p in enumerate(posterior.parameters)
    ]
    posterior = replace(posterior, parameters=parameters, likelihood_check=record)
    return posterior


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
