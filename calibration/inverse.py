"""GNS inverse design of DEM parameters (Jiang et al. 2024, section 2.3, Figs. 2, 3 and 9).

The design parameters (mu, e) sit in the node features of the initial graph; the trained GNS rolls
the measured column out from its first C frames; a differentiable runout turns the rollout into L*
at the measured t/t* points; THE objective (calibration.objective.runout_mse) scores it; scipy's
L-BFGS-B moves (mu, e) within bounds ([0.3, 0.9]^2 as the paper). Gradients come either from
automatic differentiation through the (checkpointed) rollout, or from forward differences as in
the paper's eq. (8).

The parts: calibration.gns_objective (the objective through the GNS, the geometry checks),
calibration.lbfgsb (multi-start L-BFGS-B in lockstep, the float32 finite-difference step) and
calibration.inverse_plots (the figures); here: the bounds, the whole inverse design, its posterior
and landscape, and the result file.

Every result says where its online time went: rollouts, forward and backward seconds
(InverseResult.seconds). The objective is rough below a few hundredths (calibration.gns_objective):
every result carries a roughness probe (see posterior_at).

Uncertainty: a Laplace posterior (calibration.uncertainty) from the Jacobian of L* at the optimum;
noise = the measured std (or, when the file gives none, estimated from the residuals) combined
with the surrogate's own runout error against the DEM, then held to the GNS's own chi^2 along
each interval (calibration.uncertainty.likelihood_checked: a rough rollout response must not make
an interval narrower than the likelihood); a parameter the runout cannot pin down is reported as
not identifiable.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from functools import partial

import numpy as np
from numpy.typing import ArrayLike

from calibration.bayesopt import BOSettings, bayesian_optimisation
from calibration.geometry import InverseDesignError, check_geometry
from calibration.gns_objective import DESIGN_NAMES, GNSObjective
from calibration.inverse_result import InverseResult
from calibration.lbfgsb import (
    FD_STEP,
    FTOL,
    GTOL,
    PAPER_START,
    LBFGSBSettings,
    StartResult,
    multistart_lbfgsb,
    starting_points,
)
from calibration.measured_column import MeasuredColumn
from calibration.objective import runout_mse
from calibration.optimise import OptimisationResult, PointFailed
from calibration.sensitivity import finite_or_none, sensitivity_record, untrusted_slopes
from calibration.uncertainty import (
    LaplacePosterior,
    finite_difference_jacobian,
    laplace_posterior,
    likelihood_checked,
)
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from dem.trajectory import Trajectory
from gns.simulator import LearnedSimulator

log = logging.getLogger(__name__)

BOUNDS = ((0.3, 0.9), (0.3, 0.9))
JACOBIAN_STEP = 2e-2  # central-difference step of the posterior's Jacobian, for a parameter range of PAPER_WIDTH
PAPER_WIDTH = 0.6  # the paper's box width of mu and e; a wider parameter (a Bond number) steps in proportion
# A rollout is a chaotic function of the parameters (so is the DEM): below some scale the objective
# is noise, not trend. The objective ROUGHNESS_RADIUS from the optimum, reported with every result,
# shows how large that noise is (its spread against the trend over JACOBIAN_STEP).
ROUGHNESS_RADIUS = 2e-3
# Two opposite diagonal probes: each probe is a whole rollout of online time (~10 CPU-s at 589
# grains), and the spread of three values already shows noise against the Jacobian's trend.
ROUGHNESS_PROBES = 2
OPTIMISERS = ("lbfgsb", "bayesopt")  # inverse_design's optimiser


# -- bounds ------------------------------------------------------------------------------------------
def check_bounds(
    bounds: Sequence[Sequence[float]], names: Sequence[str], parameter_ranges: dict
) -> list[tuple[float, float]]:
    """The bounds [(low, high)] * P as floats; InverseDesignError when one leaves the range the GNS
    was trained on (parameter_ranges: {name: (low, high)})."""
    bounds = [tuple(map(float, b)) for b in bounds]
    if len(bounds) != len(names):
        raise InverseDesignError(f"{len(bounds)} bounds for {len(names)} design parameters {list(names)}")
    for (low, high), name in zip(bounds, names):
        trained_low, trained_high = parameter_ranges[name]
        if not low < high:
            raise InverseDesignError(f"bounds of {name}: low {low:g} must be below high {high:g}")
        slack = 1e-6 * max(abs(trained_low), abs(trained_high), 1e-12)
        if low < trained_low - slack or high > trained_high + slack:
            raise InverseDesignError(
                f"bounds of {name} [{low:g}, {high:g}] leave the range the GNS was trained on "
                f"[{trained_low:g}, {trained_high:g}]: it would extrapolate; narrow the bounds (config "
                f"inverse.{name}) or train on a wider range"
            )
    return bounds


def design_bounds(
    bounds: Sequence[Sequence[float] | None] | None, names: Sequence[str], parameter_ranges: dict
) -> list[tuple[float, float]]:
    """Bounds of the design parameters: bounds[j] as given (checked against the trained range), or,
    where bounds[j] is None, the paper's [0.3, 0.9] narrowed to the range the GNS was trained on
    (a sampled dataset never quite reaches the ends of its sampling range)."""
    chosen = []
    for j, name in enumerate(names):
        given = None if bounds is None else bounds[j]
        if given is None:
            paper = dict(zip(DESIGN_NAMES, BOUNDS)).get(name, parameter_ranges[name])
            given = (max(paper[0], parameter_ranges[name][0]), min(paper[1], parameter_ranges[name][1]))
        chosen.append(given)
    return check_bounds(chosen, names, parameter_ranges)


# -- the whole inverse design --------------------------------------------------------------------------
def noise_level(
    measured: MeasuredColumn, model_error_std: ArrayLike | None, start_packing_std: ArrayLike | None = None
) -> np.ndarray | None:
    """Noise std [K] of the posterior, or None (estimate from residuals) when the data give none.

    The surrogate's own error (RMS of GNS - DEM L*, [K] or scalar) and the scatter of one packing's runout
    (start_packing_std, [K] or scalar, L*: every rollout starts from one packing, so the GNS
    predicts one packing's curve, not the mean over packings) add to the measured noise in
    quadrature: the posterior is of the DEM parameters, seen through an imperfect surrogate that
    runs one random packing.
    """
    if measured.runout_std is None:
        return None
    packing = 0.0 if start_packing_std is None else np.asarray(start_packing_std, float)
    model = 0.0 if model_error_std is None else np.asarray(model_error_std, float)
    return np.sqrt(np.asarray(measured.runout_std, float) ** 2 + model**2 + packing**2)


def posterior_at(
    objective: GNSObjective,
    optimum: ArrayLike,
    bounds: Sequence[Sequence[float]],
    model_error_std: ArrayLike | None = None,
    step: float | ArrayLike = JACOBIAN_STEP,
    start_packing_std: ArrayLike | None = None,
    untrusted: dict[str, str] | None = None,
) -> tuple[LaplacePosterior, np.ndarray, dict]:
    """Laplace posterior (calibration.uncertainty) at `optimum` from a central-difference Jacobian of
    the GNS's L*, and a roughness probe: the objective ROUGHNESS_RADIUS away in ROUGHNESS_PROBES
    directions. untrusted: {name: why} of parameters whose GNS slope is no evidence (laplace_posterior's:
    their intervals are their bounds). All points are asked for in one call (the objective batches
    their rollouts; none at a point rolled out before). Returns (LaplacePosterior, L* [K] at the
    optimum, roughness dict: radius, values, optimum value and their spread, to set against the
    posterior's step)."""
    optimum = np.asarray(optimum, float)
    points = []
    finite_difference_jacobian(lambda theta: points.append(np.array(theta)) or np.zeros(1), optimum, bounds, step)
    low, high = np.asarray(bounds, float).T
    angles = np.pi / 4 + np.arange(ROUGHNESS_PROBES) * 2 * np.pi / ROUGHNESS_PROBES
    # in the plane of the first two parameters (mu, e), each probe ROUGHNESS_RADIUS away
    probes = [optimum.copy() for _ in angles]
    for probe, a in zip(probes, angles):
        probe[:2] = np.clip(optimum[:2] + ROUGHNESS_RADIUS * np.array([np.cos(a), np.sin(a)]), low[:2], high[:2])
    runouts = objective.runout_values(np.vstack([optimum] + points + probes))
    ran = np.all(np.isfinite(runouts), axis=1)  # False where a rollout failed
    failed = [point for point, ok in zip(points, ran[1:]) if not ok]
    if failed:  # one-sided differences there (calibration.uncertainty.finite_difference_jacobian)
        log.warning("posterior: the rollouts at %d of %d Jacobian steps failed: %s", len(failed), len(points), failed)
    replay = iter(runouts[1 : 1 + len(points)])
    jacobian = finite_difference_jacobian(lambda theta: next(replay), optimum, bounds, step, centre=runouts[0])
    residuals = runouts[0] - objective.measured.runout
    posterior = laplace_posterior(
        objective.design_names,
        optimum,
        jacobian,
        residuals,
        bounds,
        sigma=noise_level(objective.measured, model_error_std, start_packing_std),
        untrusted=untrusted,
    )
    # None (JSON null) where a rollout failed
    values = [runout_mse(r, objective.measured.runout) if ok else None for r, ok in zip(runouts, ran)]
    probe_values = values[1 + len(points) :]
    finite = [v for v in probe_values + values[:1] if v is not None]
    roughness = {
        "radius": ROUGHNESS_RADIUS,
        "values": probe_values,
        "optimum_value": values[0],
        "spread": float(max(finite) - min(finite)),
        "jacobian_step": np.broadcast_to(step, optimum.shape).tolist() if np.ndim(step) else step,
        "jacobian_step_values": values[1 : 1 + len(points)],
    }
    return posterior, runouts[0], roughness


def landscape(objective: GNSObjective, bounds: Sequence[Sequence[float]], levels: int) -> dict:
    """The GNS objective on a levels x levels grid over two design parameters (in the objective's
    batches, no grad)."""
    axes = [np.linspace(low, high, levels) for low, high in bounds]
    grid = np.array([(a, b) for b in axes[1] for a in axes[0]])
    values = objective.values(grid)
    return {"axes": [a.tolist() for a in axes], "values": values.reshape(levels, levels).tolist()}


def inverse_design(
    simulator: LearnedSimulator,
    start: Trajectory | Sequence[Trajectory],
    measured: MeasuredColumn,
    metadata: dict,
    training_attrs: list[dict],
    bounds: Sequence[Sequence[float] | None] | None = None,
    n_starts: int = 4,
    first_start: Sequence[float] = PAPER_START,
    gradient: str = "autograd",
    fd_step: float = FD_STEP,
    max_iterations: int = 20,
    ftol: float = FTOL,
    gtol: float = GTOL,
    max_evaluations: int | None = None,
    model_error_std: ArrayLike | None = None,
    landscape_levels: int = 0,
    seed: int = 0,
    start_packing_std: ArrayLike | None = None,
    design_names: Sequence[str] = DESIGN_NAMES,
    runout: RunoutMethod | None = None,
    optimiser: str = "lbfgsb",
    budget: int = 40,
    n_initial: int = 12,
    reference: tuple[ArrayLike, ArrayLike] | None = None,
    tied: Mapping[str, str] | None = None,
) -> InverseResult:
    """Calibrate design_names against `measured` through the GNS `simulator`.

    optimiser: "lbfgsb" (the paper's: multi-start L-BFGS-B on the gradient, `gradient`) or
    "bayesopt": Bayesian optimisation of the GNS objective itself (`budget` points, the first
    `n_initial` a Latin hypercube; calibration.bayesopt), no gradient. The exact gradient of a
    rollout of a chaotic collapse grows with its length and describes the objective's roughness,
    not its trend (benchmarks/chaotic_gradient.py), so L-BFGS-B's line searches fail at its first
    step; a Gaussian process with a noise term smooths over the roughness instead.

    start: DEM trajectory of the measured column giving the first C frames, or several packings of
    it (the objective then scores their mean L*; see GNSObjective);
    metadata: the GNS dataset's metadata; training_attrs: attributes of its training trajectories
    (for the geometry check). bounds: [(low, high) or None] per design parameter (see design_bounds).
    model_error_std, start_packing_std: the posterior's model-side noise (see noise_level).
    runout: how L* is read (dem.runout.RunoutMethod; None: its default).
    reference: the DEM runs of the GNS's dataset, (parameters [n, P] in the order of design_names,
    L* [n, K] at the measured t/t*): the GNS's response to each parameter is checked against theirs
    (calibration.sensitivity); a parameter the GNS does not resolve, or resolves where the DEM is
    flat, is flagged not identifiable and its interval is its bounds (laplace_posterior's untrusted).
    tied: GNS inputs that are not designed but take a designed parameter's value (GNSObjective).
    Returns an InverseResult; seconds["online"] is the wall time of the
    optimisation and the posterior (the landscape, a figure, is timed apart).
    """
    names = list(design_names)
    bounds = design_bounds(bounds, names, metadata["parameter_ranges"])
    geometry = check_geometry(measured, metadata, training_attrs)
    runout = RunoutMethod.from_config(runout)
    objective = GNSObjective(simulator, start, measured, names, runout=runout, tied=tied)
    starts = starting_points(n_starts, bounds, first_start, seed)
    log.info(
        "inverse design of %s: %d starts, %s gradients, %d rollout steps of %d grains (%d packings)",
        measured.name,
        len(starts),
        gradient,
        objective.n_steps,
        objective.n_particles,
        objective.n_packings,
    )

    def evaluate(points):  # a point whose rollout fails is NaN: the optimiser records it and goes on
        if gradient == "autograd":
            return objective.values_and_gradients(points, allow_failed=True)
        return objective.values(points, allow_failed=True)

    # the most points the starts can ask for (each start stops at max_evaluations; with finite
    # differences each evaluation is a stencil of P + 1): the share of it done is the job's progress
    stencil = 1 if gradient == "autograd" else len(names) + 1
    most_points = len(starts) * (max_evaluations or 2 * max_iterations) * stencil
    done = progress_logger(f"inverse design of {measured.name}: points of at most {most_points}", log)
    asked = [0]

    def progress(batch, seconds, values):
        log.info(
            "batch %d: %d rollouts in %.1f s, objective %s",
            batch,
            len(values),
            seconds,
            " ".join(f"{v:.4g}" for v in values),
        )
        asked[0] += len(values)
        done(min(asked[0] / most_points, 1.0))

    t0 = time.perf_counter()
    widths = np.array([high - low for low, high in bounds])
    scale = np.maximum(widths / PAPER_WIDTH, 1.0)  # mu and e as the paper's; a wide range in proportion
    if optimiser == "bayesopt":
        budget_text = f"inverse design of {measured.name}: Bayesian optimisation, {budget} GNS points"
        optimum = bayesopt_on_gns(objective, bounds, names, BOSettings(budget, n_initial, seed), budget_text)
        gradient = "none (Bayesian optimisation)"
    elif optimiser == "lbfgsb":
        settings = LBFGSBSettings(starts, gradient, fd_step, max_iterations, ftol, gtol, max_evaluations, scale)
        optimum = multistart_lbfgsb(evaluate, bounds, names, settings, progress)
    else:
        raise InverseDesignError(f"optimiser must be one of {OPTIMISERS}, got {optimiser!r}")
    t1 = time.perf_counter()
    step = JACOBIAN_STEP * (scale if np.any(scale != 1) else 1.0)
    posterior, best_runout, roughness = posterior_at(
        objective, optimum.params, bounds, model_error_std, step, start_packing_std
    )
    sensitivity = None
    if reference is not None:
        sensitivity, _ = sensitivity_record(names, bounds, reference, objective.evaluated())
        # the GNS blind to a parameter, or responding to one the DEM hardly does: its GNS slope is no
        # evidence, so the posterior leaves it out (that parameter's interval is its bounds; the
        # others' no longer lean on it); the same rollouts, read again from the objective's cache
        untrusted = untrusted_slopes(sensitivity)
        if untrusted:
            posterior, best_runout, roughness = posterior_at(
                objective, optimum.params, bounds, model_error_std, step, start_packing_std, untrusted
            )
    # once, on the posterior that stands: a rough rollout response must not narrow an interval
    # below the GNS's own likelihood (its probes come after the sensitivity check has read the points)
    posterior = likelihood_checked(
        partial(objective.runout_values, allow_failed=True), measured.runout, posterior, bounds
    )
    t2 = time.perf_counter()
    online = dict(objective.timing)  # where the online time went: rollouts, forward, backward
    try:  # NaN (JSON null) where the first start's rollout failed
        start_runout = objective.runout_values(starts[:1])[0]
    except InverseDesignError:
        start_runout = np.full(len(measured.runout), np.nan)
    grid = landscape(objective, bounds, landscape_levels) if landscape_levels else None
    t3 = time.perf_counter()
    for p in posterior.parameters:
        log.info(
            "%s = %.4f, 95%% interval [%.4f, %.4f]%s",
            p.name,
            p.value,
            p.low,
            p.high,
            "" if p.identifiable else f" NOT identifiable: {p.why}",
        )
    return InverseResult(
        measured=measured.name,
        names=names,
        bounds=[list(b) for b in bounds],
        gradient=gradient,
        starts=optimum.starts,
        best_params=list(optimum.params),
        best_value=optimum.value,
        best_runout=best_runout.tolist(),
        start_runout=[finite_or_none(v) for v in start_runout],
        posterior=posterior.to_dict(),
        geometry=geometry,
        seconds={
            "optimisation": t1 - t0,
            "posterior": t2 - t1,
            "online": t2 - t0,
            "landscape": t3 - t2,
            "online_forward": online["forward_s"],
            "online_backward": online["backward_s"],
            "online_rollouts": online["rollouts"],
            "rollout_steps": objective.n_steps,
        },
        n_batches=optimum.n_batches,
        landscape=grid,
        model_error_std=None
        if model_error_std is None
        else np.broadcast_to(model_error_std, measured.runout.shape).tolist(),
        roughness=roughness,
        start_packing_std=None
        if start_packing_std is None
        else np.broadcast_to(start_packing_std, measured.runout.shape).tolist(),
        runout=runout.to_config(),
        failed_points=optimum.history.failed,
        optimiser=optimiser,
        sensitivity=sensitivity,
        evaluated=dict(zip(("points", "runouts"), (a.tolist() for a in objective.evaluated()))),
    )


def bayesopt_on_gns(
    objective: GNSObjective, bounds: Sequence[Sequence[float]], names: Sequence[str], settings: BOSettings, label: str
) -> OptimisationResult:
    """Bayesian optimisation of the GNS objective (one point per call, no gradient), its progress
    logged under `label`; a point whose rollout fails is a failed point (recorded, the search goes
    on). The result carries one StartResult, as a lone L-BFGS-B start would: its iterates are the
    points that lowered the best value so far, so the paths figure draws the search's progress."""
    done = progress_logger(label, log)

    def gns_point(points):
        values = objective.values(points, allow_failed=True)
        if not np.all(np.isfinite(values)):
            raise PointFailed("the GNS rollout failed or its objective is not finite there")
        return values

    def progress(calls, seconds, values):
        log.info("point %d/%d in %.1f s: objective %s", calls, settings.budget, seconds, f"{values[0]:.4g}")
        done(calls / settings.budget)

    optimum = bayesian_optimisation(gns_point, bounds, names, settings, progress)
    history = optimum.history
    improving, best = [], math.inf
    for params, value in zip(history.params, history.values):
        if value < best:
            improving.append((list(params), float(value)))
            best = value
    optimum.starts = [
        StartResult(
            start=improving[0][0],
            params=list(optimum.params),
            value=float(optimum.value),
            success=True,
            message=f"Bayesian optimisation: {history.n_calls} GNS points ({settings.n_initial} initial), "
            f"{len(history.failed)} failed",
            n_iterations=max(history.n_calls - settings.n_initial, 0),
            evaluations=history,
            iterates=improving,
        )
    ]
    return optimum
