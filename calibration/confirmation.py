"""A surrogate's optimum confirmed by the DEM: the best few distinct points a GNS search found, each
run by the DEM on packings of their own, and the one the DEM scores lowest kept.

Near its optimum a GNS objective is flat within the GNS's own error, so which of its near-best
points a search returns depends on the bits of the GNS (its training seed, the CPU's torch
kernels), and those points can lie far apart in the parameters. A point the GNS likes but the DEM
does not is then the route's answer. Running the few best distinct points through the DEM first,
on packings no calibration, validation or runoff uses (CONFIRM_SEED0 + k), lets the DEM choose
among them; the chosen point is then validated like every route's, on the validation packings, so
the choice does not flatter its validated score. Cost: candidates x packings DEM runs, counted
with the route's.

Then the DEM corrects the GNS (`refine`, an output space mapping): where the GNS's curve is off by
a bias comparable with the fit it is asked for, no point it likes is the DEM's best. The GNS's
sensitivities are still good: the slope of its L* curve in the parameters, fitted over the points
its search rolled out near the chosen one, gives a Gauss-Newton step for the DEM's own residual
there, bounded by a trust region in the unit box. Each step runs on the confirmation packings; a
step the DEM scores lower is taken, else the region halves. The shape comes from the GNS, the
level from the DEM. Cost: rounds x packings DEM runs more.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from calibration.calibrated import CalibrationError, Validation, validate
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.sensitivity import finite_or_none
from dem.runout import RunoutMethod

CONFIRM_SEED0 = 7001  # confirmation packings: no calibration's, validation's (5001...) or diagnosis' seed
# Candidates this far apart at least, in the model's unit box (log axes where it has them): farther
# than the refinement's first step (TRUST_RADIUS), so that they sample other stretches of the flat
# valley a GNS cannot tell apart, not one stretch the refinement would cover from one of them. At 0.1
# one GNS (seed 0, ATEN default) put all three at mu 0.73-0.88, which the DEM scored 0.21-0.40, and
# validated at 0.122; at 0.3 its third candidate lay elsewhere and it validated at 0.070
# (docs/experiments/route-spread.md).
MIN_UNIT_DISTANCE = 0.3
# The first refinement step's largest move per parameter, in the unit box: about the spread of the
# near-best points of one GNS search over its training seeds (0.04-0.06 in mu_w of a 0.1-0.6 box,
# docs/experiments/gns-route.md), with room to spare.
TRUST_RADIUS = 0.25
# The kernel width (unit box) of the local linear fit of the GNS's L*: wide enough to average over
# the rollout's roughness at a few hundredths, narrow enough to stay local.
SLOPE_BANDWIDTH = 0.15


@dataclass
class Confirmation:
    """The DEM's check of a surrogate's best points.

    candidates [n]: each point's Validation on the confirmation packings (seeds CONFIRM_SEED0 + k),
    its route naming its rank; surrogate_values [n]: the surrogate's objective at each; steps [s]:
    the refinement's points (`refine`), on the same packings; predicted [s]: the MSE each step's
    linear model foresaw; chosen: the index, over candidates then steps, of the lowest DEM MSE
    (the surrogate's best where every run failed); slope [K, p]: d L* / d u (unit box) the
    refinement ended with at the chosen point, secant-corrected where it was (None: no refinement;
    kept for the job, not written)."""

    candidates: list[Validation]
    surrogate_values: list[float]
    chosen: int
    steps: list[Validation] = field(default_factory=list)
    predicted: list[float] = field(default_factory=list)
    slope: np.ndarray | None = None

    @property
    def checked(self) -> list[Validation]:
        """[n + s] every point the DEM ran: the candidates, then the refinement's steps."""
        return self.candidates + self.steps

    @property
    def dem_runs(self) -> int:
        """The DEM runs made: candidates x packings, a failed run counted too."""
        return sum(len(c.seeds) for c in self.checked)

    @property
    def seconds(self) -> float:
        """The DEM's wall time over every point it ran."""
        return sum(c.seconds for c in self.checked)

    @property
    def theta(self) -> list[float]:
        """The chosen point's parameters [p], in the model's order."""
        return list(self.checked[self.chosen].parameters.values())

    def to_dict(self) -> dict:
        """JSON: per candidate and per step its parameters, seeds, curves [R][K] (None where a run
        failed), failed {seed: reason}, mse of the mean curve and mse_each [R] (None where not
        finite); chosen indexes candidates then steps."""

        def point(c: Validation) -> dict:
            return {
                "parameters": c.parameters,
                "seeds": c.seeds,
                "curves": c.curves,
                "failed": c.failed,
                "mse": finite_or_none(c.mse),
                "mse_each": [finite_or_none(v) for v in c.mse_each],
            }

        return {
            "candidates": [point(c) for c in self.candidates],
            "surrogate_values": [finite_or_none(v) for v in self.surrogate_values],
            "steps": [point(c) for c in self.steps],
            "predicted": [finite_or_none(v) for v in self.predicted],
            "chosen": self.chosen,
            "dem_runs": self.dem_runs,
        }


def distinct_best(
    points: np.ndarray, values: np.ndarray, model: Model, n: int, min_distance: float = MIN_UNIT_DISTANCE
) -> list[int]:
    """Indices of up to n points [m, p] of lowest finite `values` [m], each at least min_distance
    (Euclidean, in the model's unit box) from every lower-valued one kept: the best point first."""
    finite = np.flatnonzero(np.isfinite(values))
    order = finite[np.argsort(values[finite], kind="stable")]
    unit = model.box.to_unit(np.asarray(points, float))
    kept: list[int] = []
    for index in order:
        if all(np.linalg.norm(unit[index] - unit[k]) >= min_distance for k in kept):
            kept.append(int(index))
            if len(kept) == n:
                break
    return kept


def confirm(
    model: Model,
    column: MeasuredColumn,
    points: Sequence[Sequence[float]],
    values: Sequence[float],
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_candidates: int = 3,
    n_packings: int = 2,
    progress: Callable[[float], None] | None = None,
) -> Confirmation:
    """The n_candidates distinct best (distinct_best) of a surrogate's evaluated `points` [m, p]
    (values [m]: its objective there, NaN where it failed) run by the DEM on n_packings packings of
    their own; the one whose mean curve has the lowest runout MSE is chosen."""
    points, values = np.asarray(points, float), np.asarray(values, float)
    picked = distinct_best(points, values, model, n_candidates)
    if not picked:
        raise CalibrationError(f"{column.name}: no finite surrogate value among {len(values)} points to confirm")
    candidates = []
    for rank, index in enumerate(picked):
        within = None if progress is None else (lambda f, rank=rank: progress((rank + f) / len(picked)))
        theta, label = points[index], f"candidate {rank + 1}"
        own = {"progress": within, "seed0": CONFIRM_SEED0}
        candidates.append(validate(label, model, column, theta, settings, runout, dem_config, n_packings, **own))
    scores = [c.mse if math.isfinite(c.mse) else math.inf for c in candidates]
    chosen = int(np.argmin(scores)) if math.isfinite(min(scores)) else 0
    return Confirmation(candidates, [float(values[i]) for i in picked], chosen)


def local_slope(
    unit_points: np.ndarray, runouts: np.ndarray, centre: np.ndarray, bandwidth: float = SLOPE_BANDWIDTH
) -> np.ndarray:
    """d L* / d u [K, p] at `centre` [p] (unit box) of a surrogate's L* curves runouts [n, K] at
    unit_points [n, p]: a linear fit weighted by a Gaussian kernel of `bandwidth`, widened (x 1.5,
    up to the whole box) until the weights count at least 2 (p + 1) points, so that the slope
    averages over the rollout's roughness instead of following it."""
    unit_points, runouts = np.asarray(unit_points, float), np.asarray(runouts, float)
    keep = np.all(np.isfinite(unit_points), axis=1) & np.all(np.isfinite(runouts), axis=1)
    unit_points, runouts = unit_points[keep], runouts[keep]
    n, p = unit_points.shape
    if n < p + 1:
        raise CalibrationError(f"a slope in {p} parameters needs {p + 1} surrogate points, got {n}")
    offsets = unit_points - centre
    distance2 = np.sum(offsets**2, axis=1)
    width = bandwidth
    while True:
        weights = np.exp(-0.5 * distance2 / width**2)
        effective = weights.sum() ** 2 / max(np.sum(weights**2), 1e-300)
        if effective >= 2 * (p + 1) or width >= 1.0:
            break
        width *= 1.5
    design = np.hstack([np.ones((n, 1)), offsets]) * np.sqrt(weights)[:, None]
    coefficients, *_ = np.linalg.lstsq(design, runouts * np.sqrt(weights)[:, None], rcond=None)
    return coefficients[1:].T


def refine(
    model: Model,
    column: MeasuredColumn,
    confirmation: Confirmation,
    gns_points: np.ndarray,
    gns_runouts: np.ndarray,
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_rounds: int,
    progress: Callable[[float], None] | None = None,
    secant: bool = False,
) -> Confirmation:
    """The confirmation's chosen point corrected by the DEM in n_rounds Gauss-Newton steps (the
    module's docstring): the step minimises |DEM mean L* + S du - measured L*|^2 within the unit box
    and the trust region, S the GNS's local slope (local_slope of gns_runouts [n, K] at gns_points
    [n, p], the model's parameter order); each step runs on the confirmation's packings. secant:
    after each step S is corrected by what the DEM's curve did along it (Broyden's rank-one update,
    as aggressive space mapping does), where the surrogate's slopes differ from the DEM's by more
    than its local fit shows (another scale's DEM). Returns the confirmation with the steps, the
    predicted MSEs and the lowest DEM MSE chosen."""
    box = model.box
    unit_points = box.to_unit(gns_points)
    current = confirmation.checked[confirmation.chosen]
    n_packings, measured = len(current.seeds), np.asarray(column.runout, float)
    radius, steps, predicted = TRUST_RADIUS, [], []
    learnt = 0.0  # the secant's correction of the surrogate's slope [K, p]
    for round_ in range(n_rounds):
        if not math.isfinite(current.mse):
            break
        centre = box.to_unit(list(current.parameters.values()))[0]
        slope = local_slope(unit_points, gns_runouts, centre) + learnt
        residual = measured - np.asarray(current.mean, float)
        move = damped_step(slope, residual, centre, radius, current)
        if np.max(np.abs(move)) < 1e-3:  # the linear model sees no better point within the region
            break
        theta = box.from_unit(centre + move)[0]
        within = None if progress is None else (lambda f, r=round_: progress((r + f) / n_rounds))
        step = validate(
            f"refinement {round_ + 1}", model, column, theta, settings, runout, dem_config, n_packings,
            progress=within, seed0=CONFIRM_SEED0,
        )  # fmt: skip
        steps.append(step)
        predicted.append(float(np.mean((residual - slope @ move) ** 2)))
        if secant and math.isfinite(step.mse) and float(move @ move) > 0:  # a step of no length teaches no slope
            missed = np.asarray(step.mean, float) - np.asarray(current.mean, float) - slope @ move
            learnt = learnt + np.outer(missed, move) / float(move @ move)
        if math.isfinite(step.mse) and step.mse < current.mse:
            current = step
        else:
            radius /= 2
    checked = confirmation.checked + steps
    scores = [c.mse if math.isfinite(c.mse) else math.inf for c in checked]
    chosen = int(np.argmin(scores)) if math.isfinite(min(scores)) else confirmation.chosen
    centre = box.to_unit(list(checked[chosen].parameters.values()))[0]
    return Confirmation(
        confirmation.candidates, confirmation.surrogate_values, chosen,
        confirmation.steps + steps, confirmation.predicted + predicted,
        slope=local_slope(unit_points, gns_runouts, centre) + learnt,
    )  # fmt: skip


def damped_step(
    slope: np.ndarray, residual: np.ndarray, centre: np.ndarray, radius: float, current: Validation
) -> np.ndarray:
    """The move du [p] (unit box) minimising |residual [K] - slope [K, p] du|^2 within the unit box
    about `centre` [p] and the trust region of `radius`, damped (Levenberg-Marquardt): a move the
    whole radius long costs as much as the noise of the residual (the packing scatter of
    `current`'s mean curve), so a parameter the curve hardly feels is not pushed to the region's
    edge on noise."""
    from scipy.optimize import lsq_linear

    n_packings = len(current.seeds)
    low, high = np.maximum(-centre, -radius), np.minimum(1.0 - centre, radius)
    noise = np.nanmean(np.square(current.std)) / n_packings if n_packings > 1 else 0.0
    damping = math.sqrt(len(residual) * noise) / radius if math.isfinite(noise) else 0.0
    augmented = np.vstack([slope, damping * np.eye(len(centre))])
    target = np.concatenate([residual, np.zeros(len(centre))])
    return lsq_linear(augmented, target, bounds=(low, high + 1e-12)).x
