"""The differentiable twin of dem.runout: L* of a (GNS) rollout that autograd can go through.

Each method of dem.runout.RunoutMethod is followed exactly in its discrete choices and smoothed
only where a gradient has to pass:
- which grains may hold the front (the connected deposit, or the dense grains) is the same mask,
  taken on the detached positions: like the GNS radius graph, membership carries no gradient;
- the connected front's mean of the n_leading leading grains becomes a soft top-k mean, the dense
  front's farthest grain a soft top-1, both of width `temperature` mean grain diameters
  (`soft_top_k_mean`); they tend to dem.runout's values as the temperature goes to 0;
- the running maximum of the `_reached` methods is torch.cummax, exact, whose gradient goes to
  the frame that set the maximum.
tests/test_inverse.py checks every method against dem.runout on DEM trajectories (within 0.25 d).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numpy.typing import ArrayLike
from scipy.optimize import brentq
from scipy.special import expit

from dem.runout import RunoutError, RunoutMethod

SOFT_TEMPERATURE = 0.25  # soft top-k width, in mean grain diameters (connected front)
# The dense front is one grain: its soft top-1 must be narrower to stay within 0.25 d of the max.
SOFT_TEMPERATURE_TOP1 = 0.05


def soft_top_k_mean(values: torch.Tensor, k: int, temperature: float) -> torch.Tensor:
    """Smooth mean of the k largest of `values` [n] (same units as temperature).

    Weights w_i = sigmoid((v_i - c) / temperature) with sum w = k; c is found on detached values
    and its gradient added by the implicit-function theorem (dc/dv_i = s_i / sum s, s = w (1 - w)),
    so the result's gradient is exact for the smooth function. n <= k gives the plain mean.
    """
    if values.numel() <= k:
        return values.mean()
    v = values.detach().double().cpu().numpy()
    excess = lambda c: float(np.sum(expit((v - c) / temperature))) - k  # noqa: E731
    low, high = v.min() - 50 * temperature, v.max() + 50 * temperature
    c0 = brentq(excess, low, high, xtol=1e-12 * max(1.0, abs(high)))
    w0 = expit((v - c0) / temperature)
    slope = torch.as_tensor(w0 * (1.0 - w0), dtype=values.dtype, device=values.device)
    # A leader far ahead of the rest (~100 widths; a dense clump ahead of the copper column) leaves every
    # slope under float32's range: the guard must be of the tensor's dtype (1e-300 is 0 in float32, and
    # 0 / 0 made the GNS objective NaN); then c carries no gradient and the result is the hard top-k.
    threshold = c0 + torch.sum(slope * (values - values.detach())) / max(
        float(slope.sum()), torch.finfo(values.dtype).tiny
    )
    weights = torch.sigmoid((values - threshold) / temperature)
    return torch.sum(weights * values) / torch.sum(weights)


def soft_front_position(
    positions: torch.Tensor,
    radius: torch.Tensor,
    method: RunoutMethod,
    temperature: float | None = None,
    where: str = "frame",
) -> torch.Tensor:
    """Differentiable L (m) of one frame by `method`'s instantaneous rule.

    positions [N, 2] (m), radius [N] (m); temperature in mean grain diameters (None: the rule's
    default, SOFT_TEMPERATURE or SOFT_TEMPERATURE_TOP1).
    """
    radius_np = radius.detach().cpu().numpy().astype(np.float64)
    mask = method.front_mask(positions.detach().cpu().numpy(), radius_np)
    if not mask.any():
        raise RunoutError(f"{where}: no grain qualifies for the {method.front_rule} rule ({method.label})")
    index = torch.as_tensor(np.flatnonzero(mask), device=positions.device)
    front = positions[index, 0] + radius[index]
    dense = method.front_rule == "dense_front"
    if temperature is None:
        temperature = SOFT_TEMPERATURE_TOP1 if dense else SOFT_TEMPERATURE
    k = 1 if dense else method.n_leading
    return soft_top_k_mean(front, k, temperature * 2.0 * float(radius_np.mean()))


def frame_weights(t_points: ArrayLike, t_star: float, dt_frame: float, n_frames: int) -> list[tuple[int, float]]:
    """[(frame k, weight w)] per t/t* point of t_points [K]: L*(t) = (1 - w) L*[k] + w L*[k + 1], as
    np.interp on the frame times (frame j at t = j dt_frame)."""
    pairs = []
    for t in np.asarray(t_points, float):
        u = t * t_star / dt_frame
        k = min(int(math.floor(u + 1e-9)), n_frames - 2)
        pairs.append((k, float(np.clip(u - k, 0.0, 1.0))))
    return pairs


def frames_needed(t_points: ArrayLike, t_star: float, dt_frame: float) -> int:
    """How many frames (from frame 0) a runout at the t/t* points reads."""
    return max(k for k, _ in frame_weights(t_points, t_star, dt_frame, 10**9)) + 2


def soft_runout_at(
    positions: torch.Tensor,
    radius: torch.Tensor,
    L_i: float,
    t_star: float,
    dt_frame: float,
    t_points: ArrayLike,
    method: RunoutMethod,
    temperature: float | None = None,
) -> torch.Tensor:
    """Differentiable L* [K] at t/t* points from frames positions [T, N, 2] (m), frame j at j dt_frame."""
    pairs = frame_weights(t_points, t_star, dt_frame, positions.shape[0])
    if method.reached:  # every frame up to the last point sets the running maximum
        last = max(k + (w > 0) for k, w in pairs)
        fronts = torch.stack(
            [
                soft_front_position(positions[k], radius, method, temperature, where=f"frame {k}")
                for k in range(last + 1)
            ]
        )
        runout = (torch.cummax(fronts, dim=0).values - L_i) / L_i
        return torch.stack([(1.0 - w) * runout[k] + w * runout[k + 1] if w > 0 else runout[k] for k, w in pairs])
    cache = {}

    def runout(k):
        if k not in cache:
            cache[k] = (soft_front_position(positions[k], radius, method, temperature, where=f"frame {k}") - L_i) / L_i
        return cache[k]

    return torch.stack([(1.0 - w) * runout(k) + w * runout(k + 1) if w > 0 else runout(k) for k, w in pairs])
