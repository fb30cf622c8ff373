"""Does the GNS see each parameter? Its runout's response to every design parameter against the
DEM's, over the box the inverse design searches.

A GNS can fit its training runs on average and still ignore one of its inputs. The calibrated quartz
GNS (cohesion) rolled out L*(t/t* = 3.5) between 6.0 and 6.7 over its whole Bond-number range, where
the DEM runs of its own dataset fall from about 8.3 to 4.4 (docs/experiments/gns-route.md). An inverse
design through such a GNS moves that parameter on noise, and its posterior, linearised on the GNS,
cannot know. The check, run with every inverse design that has its dataset's DEM runs:

  - a linear fit of the last measured L* on the parameters, each scaled to [0, 1] over the bounds,
    to the DEM runs of the GNS's dataset, and to the GNS's own points of the inverse design;
  - per parameter, the two slopes (the change of L* across the box) with their standard errors;
  - a parameter the DEM responds to (slope at least SIGNIFICANT standard errors) is resolved when
    the GNS's slope has its sign and lies within a factor RESOLVED_FACTOR of it, and not resolved
    when it lies outside that band by more than SIGNIFICANT standard errors of the difference
    (between the two: too uncertain to tell, None, as where the DEM hardly responds);
  - a parameter the DEM hardly responds to but the GNS does (its slope at least SIGNIFICANT of its
    own standard errors, and outside the 95% interval of the DEM's slope) is `gns_only`: the GNS's
    posterior interval of it rests on a response the DEM runs do not show, so the inverse design
    flags it not identifiable. (The calibrated quartz GNS of 2026-11-30: L* +1.14 +- 0.12 across mu,
    the DEM +0.07 +- 0.35; 2.9 standard errors of the difference, short of a `resolved: False`, yet
    its mu interval was the GNS's alone. Its restitution, +1.11 +- 0.15 against the DEM's +0.90 +-
    0.37, is not: the DEM's runs are too few to call that response, but they show it.)

The GNS's points sit where the optimiser looked (a Latin hypercube, then near its optimum), so its
slope is of that region: a local view, enough to tell a parameter seen from one ignored.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from calibration.uncertainty import Z95  # a slope outside the DEM's +- Z95 SE: a response it does not show

log = logging.getLogger(__name__)

SIGNIFICANT = 3.0  # |slope| / its standard error above which the DEM responds to a parameter
RESOLVED_FACTOR = 2.0  # the GNS's slope within [1/2, 2] of the DEM's: the GNS sees the parameter


@dataclass
class ParameterResponse:
    """The response of the last measured L* to one parameter across its bounds (L*), by the DEM and
    by the GNS, with standard errors; resolved: True, False, or None where the DEM hardly responds
    (nothing to resolve) or the fits are too uncertain to tell; gns_only: the DEM hardly responds
    but the GNS does; why: plain words when not True."""

    name: str
    dem: float
    dem_se: float
    gns: float
    gns_se: float
    resolved: bool | None
    why: str
    gns_only: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


def response_slopes(points: ArrayLike, values: ArrayLike, bounds: Sequence[Sequence[float]]) -> tuple:
    """(slopes [P], standard errors [P]) of the least-squares plane values ~ a + sum_j s_j u_j, u_j =
    (points_j - low_j) / (high_j - low_j): s_j is the change of the value across parameter j's
    bounds. points [n, P], values [n]; a point whose value is not finite (a rollout that failed) is
    left out; the others must exceed P + 1 (ValueError otherwise)."""
    points, values = np.atleast_2d(np.asarray(points, float)), np.asarray(values, float)
    finite = np.isfinite(values) & np.all(np.isfinite(points), axis=1)
    points, values = points[finite], values[finite]
    low, high = np.asarray(bounds, float).T
    n, p = points.shape
    if n <= p + 1:
        raise ValueError(f"{n} points with a finite value cannot fit a plane in {p} parameters with a standard error")
    design = np.column_stack([np.ones(n), (points - low) / (high - low)])
    coefficients, _, rank, _ = np.linalg.lstsq(design, values, rcond=None)
    if rank < p + 1:
        raise ValueError(f"the {n} points do not span the {p} parameters")
    residual = values - design @ coefficients
    variance = residual @ residual / (n - p - 1)
    se = np.sqrt(variance * np.diag(np.linalg.inv(design.T @ design)))
    return coefficients[1:], se[1:]


def parameter_sensitivity(
    names: Sequence[str],
    bounds: Sequence[Sequence[float]],
    dem_points: ArrayLike,
    dem_runout: ArrayLike,
    gns_points: ArrayLike,
    gns_runout: ArrayLike,
) -> list[ParameterResponse]:
    """Per parameter of `names`, the DEM's and the GNS's response of the last L* across `bounds`.

    dem_points [n, P] and dem_runout [n, K]: the DEM runs of the GNS's dataset (parameters in the
    order of names, L* at the measured t/t*); gns_points [m, P], gns_runout [m, K]: the points the
    inverse design rolled out and their (mean over packings) L*."""
    dem, dem_se = response_slopes(dem_points, np.asarray(dem_runout, float)[:, -1], bounds)
    gns, gns_se = response_slopes(gns_points, np.asarray(gns_runout, float)[:, -1], bounds)
    out = []
    for j, name in enumerate(names):
        said = (
            f"across its bounds the GNS's L* moves by {gns[j]:+.2f} +- {gns_se[j]:.2f}, "
            f"the DEM's by {dem[j]:+.2f} +- {dem_se[j]:.2f}"
        )
        gns_only = False
        if abs(dem[j]) < SIGNIFICANT * dem_se[j]:
            resolved = None
            gns_only = bool(abs(gns[j]) >= SIGNIFICANT * gns_se[j] and abs(gns[j] - dem[j]) > Z95 * dem_se[j])
            why = f"the DEM hardly responds to it{', the GNS does' if gns_only else ''}: {said}"
        elif 1 / RESOLVED_FACTOR <= gns[j] / dem[j] <= RESOLVED_FACTOR:
            resolved, why = True, ""
        elif abs(gns[j] - dem[j]) < SIGNIFICANT * np.hypot(gns_se[j], dem_se[j]):
            # outside the band, but within the two fits' errors: a flag needs evidence too
            resolved, why = None, f"too uncertain to tell: {said}"
        else:
            resolved, why = False, f"the GNS does not resolve it: {said}"
        out.append(
            ParameterResponse(
                name, float(dem[j]), float(dem_se[j]), float(gns[j]), float(gns_se[j]), resolved, why, gns_only
            )
        )
    return out


def sensitivity_record(
    names: Sequence[str], bounds: Sequence[Sequence[float]], dem: tuple, gns: tuple
) -> tuple[dict, list[ParameterResponse]]:
    """The check as an inverse design records it (InverseResult.sensitivity) and its responses.

    dem, gns: (points [n, P], L* [n, K]) as parameter_sensitivity takes them. The record:
    {"why": "" or why not checked, "parameters": [ParameterResponse.to_dict()], "dem" and "gns":
    {"points" [n][P], "last" [n]}} (the points, for the figure). Too few runs or points for a
    plane in every parameter: not checked (no responses), the record says why."""
    responses, why = [], ""
    try:
        responses = parameter_sensitivity(names, bounds, *dem, *gns)
    except ValueError as exc:
        why = f"not checked: {exc}"
        log.warning("the GNS's response to its parameters is %s", why)
    for r in responses:
        log.info(
            "%s: L* across the bounds GNS %+.2f +- %.2f, DEM %+.2f +- %.2f (resolved: %s)",
            r.name,
            r.gns,
            r.gns_se,
            r.dem,
            r.dem_se,
            r.resolved,
        )
    record = {
        "why": why,
        "parameters": [r.to_dict() for r in responses],
        **{
            key: {"points": np.asarray(points).tolist(), "last": [finite_or_none(v) for v in np.asarray(runout)[:, -1]]}
            for key, (points, runout) in (("dem", dem), ("gns", gns))
        },
    }
    return record, responses


def untrusted_slopes(record: dict | None) -> dict[str, str]:
    """{name: why} of the parameters whose GNS slope the check rejects, from a sensitivity_record
    record (None: none checked): those the GNS does not resolve, and those it responds to where the
    DEM is flat (gns_only). Their slope is no evidence (calibration.uncertainty's untrusted)."""
    parameters = (record or {}).get("parameters", [])
    return {p["name"]: p["why"] for p in parameters if p["resolved"] is False or p["gns_only"]}


def finite_or_none(value: float) -> float | None:
    """value, or None (JSON null) where a rollout failed: the records' one way to write a missing L*."""
    return float(value) if np.isfinite(value) else None
