"""GNS inverse design of DEM parameters (Jiang et al. 2024, section 2.3, Figs. 2, 3 and 9).

The design parameters (mu, e) sit in the node features of the initial graph; the trained GNS rolls
the measured column out from its first C frames; a differentiable runout turns the rollout into L*
at the measured t/t* points; THE objective (calibration.objective.runout_mse) scores it; scipy's
L-BFGS-B moves (mu, e) within bounds ([0.3, 0.9]^2 as the paper). Gradients come either from
automatic differentiation through the (checkpointed) rollout, or from forward differences as in
the paper's eq. (8) -- with a step the float32 model resolves: scipy's default 1e-8 vanishes in
float32 (0.31 + 1e-8 == 0.31), so the differences are exactly zero and L-BFGS-B stops at its start.

Several starts run in lockstep: each is its own L-BFGS-B (its path is the one a lone run would
take), and the points they ask for at the same moment are rolled out as one batch of graphs; with
finite differences each start asks for its whole stencil (x and x + h e_j) at once. Rollouts stop
at the last measured t/t* (the frames the runout needs), a differentiated rollout runs in
checkpointed segments whose forward pass carries no autograd bookkeeping, and no point is rolled
out twice (the posterior reuses the optimum's runout). Every result says where its online time
went: rollouts, forward and backward seconds (InverseResult.seconds).

A rollout is chaotic in (mu, e), as the DEM is: below a few hundredths the objective is rough and
its exact gradient is large and local. So line searches may fail; each start keeps its best
evaluated point and says so, and every result carries a roughness probe (see posterior_at).

Uncertainty: a Laplace posterior (calibration.uncertainty) from the Jacobian of L* at the optimum;
noise = the measured std (or, when the file gives none, estimated from the residuals) combined
with the surrogate's own runout error against the DEM; a parameter the runout cannot pin down is
reported as not identifiable.

Differentiable runout: gns.runout, the twin of dem.runout's configured method (`runout`, a
dem.runout.RunoutMethod): the same discrete choice of grains, a soft top-k where dem.runout takes
a mean or a maximum, an exact running maximum for the "_reached" methods.
"""
from __future__ import annotations

import logging
import math
import threading
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.optimize import OptimizeResult, minimize

from calibration.bayesopt import OptimisationHistory
from calibration.measured import MeasuredColumn
from calibration.objective import runout_mse
from calibration.uncertainty import finite_difference_jacobian, laplace_posterior
from dem.runout import RunoutError, RunoutMethod
from dem.trajectory import Trajectory
from gns.runout import frames_needed, soft_runout_at

log = logging.getLogger(__name__)

DESIGN_NAMES = ("friction", "restitution")
BOUNDS = ((0.3, 0.9), (0.3, 0.9))
PAPER_START = (0.55, 0.73)            # the paper's starting point (Fig. 2, loss 0.66)
SCIPY_DEFAULT_STEP = 1e-8             # scipy's L-BFGS-B `eps`, the step of the paper's public code
# Forward-difference step for the float32 GNS. The rounding error of a float32 objective is
# ~1e-7 relative, so a step h gives a gradient error ~1e-7 / h; the radius graph also switches
# edges on and off, which puts small jumps in the objective. 1e-2 (1.7% of the [0.3, 0.9] range)
# averages over both and still resolves the curvature of the runout (tests/test_inverse.py).
FD_STEP = 1e-2
JACOBIAN_STEP = 2e-2                  # central-difference step of the posterior's Jacobian
# A rollout is a chaotic function of the parameters (so is the DEM): below some scale the objective
# is noise, not trend. The objective ROUGHNESS_RADIUS from the optimum, reported with every result,
# shows how large that noise is (its spread against the trend over JACOBIAN_STEP).
ROUGHNESS_RADIUS = 2e-3
# Two opposite diagonal probes: each probe is a whole rollout of online time (~10 CPU-s at 589
# grains), and the spread of three values already shows noise against the Jacobian's trend.
ROUGHNESS_PROBES = 2
# Rollout steps per checkpointed segment of a differentiated rollout (GNSObjective._rollout): the
# backward pass holds one segment's activations, ~40 MB per step per 589-grain graph at latent 64.
SEGMENT_STEPS = 10
GEOMETRY_TOLERANCE = 0.05             # relative distance to the nearest training case that warns
GRADIENTS = ("autograd", "finite-difference")
# Stopping: an objective change below FTOL (relative to max(|f|, 1)) or a projected gradient below
# GTOL is far below what the data resolve: with 7 points of noise 0.05 in L*, the MSE itself
# scatters by ~1e-3 between two measurements, and a gradient of 1e-3 moves it by 1e-4 over a
# whole 0.1 step in mu. GNS objectives are rough (the radius graph switches edges), and tighter
# tests only make L-BFGS-B retry its line search on that roughness, one rollout per retry;
# MAX_LINE_SEARCH caps those retries.
FTOL = 1e-4
GTOL = 1e-3
MAX_LINE_SEARCH = 10
# A start stops after STALL_EVALUATIONS evaluations in a row that do not lower its best objective
# by more than ftol * max(|best|, 1): on a rough GNS objective the exact (autograd) gradient is
# local, and L-BFGS-B's line search then retries tiny steps, one rollout each, that change nothing
# (measured: 28.1 -> 22.93 -> 22.95 -> 22.93 -> 22.93 ...). The start keeps its best point and says so.
STALL_EVALUATIONS = 3


class _Stalled(Exception):
    """A start's last STALL_EVALUATIONS evaluations did not improve on its best."""


class InverseDesignError(ValueError):
    """The inverse design cannot give a trustworthy optimum; the message says why."""


class GeometryWarning(UserWarning):
    """The measured column lies away from every column the GNS was trained on."""


# -- float32 resolution -----------------------------------------------------------------------------
def step_vanishes(value: float, step: float, dtype=np.float32) -> bool:
    """True when value + step rounds back to value in `dtype` (the FD difference is then zero)."""
    return bool(dtype(value) + dtype(step) == dtype(value))


def check_step(step: float, bounds, dtype=np.float32) -> None:
    """InverseDesignError when a finite-difference step vanishes somewhere in the bounds."""
    for low, high in bounds:
        for value in (low, high, 0.5 * (low + high)):
            if step_vanishes(value, step, dtype):
                raise InverseDesignError(
                    f"finite-difference step {step:g} vanishes in {np.dtype(dtype).name} at {value:g} "
                    f"({value:g} + {step:g} == {value:g}): the differences would be exactly zero; "
                    f"use a step above {np.spacing(dtype(high)):.2g} (default {FD_STEP:g})")


# -- the objective through the GNS --------------------------------------------------------------
def check_geometry(measured: MeasuredColumn, metadata: dict, training_attrs: list[dict]) -> dict:
    """Where the measured column lies relative to the GNS's training columns.

    training_attrs: attributes of the training trajectories. Returns {"distance": relative
    distance to the nearest training column in (aspect_ratio, L_i), "nearest": its (a, L_i)}.
    InverseDesignError for another material or a column outside the trained L_i/H_i range (the
    model refuses those inputs); GeometryWarning (with the distance) when no training column is
    within GEOMETRY_TOLERANCE.
    """
    materials = metadata.get("materials") or sorted({str(a["material"]) for a in training_attrs})
    if measured.material not in materials:
        raise InverseDesignError(f"measured column {measured.name!r} ({measured.source}) is {measured.material}; "
                                 f"the GNS was trained on {materials} only (it has no material input)")
    ranges = metadata["parameter_ranges"]
    outside = []
    for key, value in (("L_i", measured.L_i), ("H_i", measured.H_i), ("aspect_ratio", measured.aspect_ratio)):
        low, high = ranges[key]
        if value < low * (1 - 1e-6) or value > high * (1 + 1e-6):
            off = (low - value) if value < low else (value - high)
            outside.append(f"{key} = {value:g} lies outside [{low:g}, {high:g}] (by {off:g}, "
                           f"{off / max(abs(value), 1e-12):.0%})")
    if outside:
        raise InverseDesignError(
            f"measured column {measured.name!r} ({measured.source}) lies outside the geometry the GNS was trained "
            f"on: {'; '.join(outside)}; train the GNS on this geometry (a dataset with its material, aspect "
            "ratio and L_i)")
    columns = np.array([[float(a["aspect_ratio"]), float(a["L_i"])] for a in training_attrs])
    target = np.array([measured.aspect_ratio, measured.L_i])
    relative = np.max(np.abs(columns - target) / target, axis=1)
    nearest = int(np.argmin(relative))
    distance = float(relative[nearest])
    if distance > GEOMETRY_TOLERANCE:
        warnings.warn(f"measured column {measured.name!r} (a = {measured.aspect_ratio:g}, L_i = {measured.L_i:g} m) "
                      f"is {distance:.0%} away from the nearest training column (a = {columns[nearest, 0]:g}, "
                      f"L_i = {columns[nearest, 1]:g} m): the GNS interpolates between geometries here",
                      GeometryWarning, stacklevel=2)
    return {"distance": distance, "nearest": columns[nearest].tolist()}


def nearest_dataset(measured: MeasuredColumn, rows: list[dict], datasets) -> str:
    """The dataset (among `datasets`) whose training columns come nearest the measured one.

    rows: case-table rows (dem.grid) with dataset, split, material, aspect_ratio, L_i. Only datasets
    of the measured material count; the distance is the largest relative difference in (a, L_i).
    """
    best, best_distance = None, math.inf
    for row in rows:
        if row["dataset"] not in datasets or row["split"] != "train" or row["material"] != measured.material:
            continue
        distance = max(abs(float(row["aspect_ratio"]) - measured.aspect_ratio) / measured.aspect_ratio,
                       abs(float(row["L_i"]) - measured.L_i) / measured.L_i)
        if distance < best_distance:
            best, best_distance = row["dataset"], distance
    if best is None:
        raise InverseDesignError(f"measured column {measured.name!r} ({measured.source}) is {measured.material}; "
                                 f"no GNS dataset among {sorted(datasets)} has {measured.material} training cases")
    return best


def check_geometry_of_dataset(measured: MeasuredColumn, rows: list[dict], dataset: str) -> dict:
    """check_geometry from case-table rows (before any DEM run): the dataset's parameter ranges
    over all its rows (as dem.dataset computes them) and its training rows as the training set."""
    mine = [dict(r, H_i=float(r["aspect_ratio"]) * float(r["L_i"])) for r in rows if r["dataset"] == dataset]
    ranges = {k: [min(float(r[k]) for r in mine), max(float(r[k]) for r in mine)] for k in ("L_i", "H_i", "aspect_ratio")}
    metadata = {"materials": sorted({str(r["material"]) for r in mine}), "parameter_ranges": ranges}
    return check_geometry(measured, metadata, [r for r in mine if r["split"] == "train"])


class GNSObjective:
    """THE objective of design parameters through a GNS rollout of the measured column.

    start: a DEM trajectory of the measured column (material, a, L_i; the GNS's grain size and
    frame interval) whose first C frames start every rollout; the design parameters replace its
    own. Parameters the model takes but that are not designed keep the start's values.
    Call with theta [G, P] (P = len(design_names)): G rollouts run as one batch of graphs.
    """

    def __init__(self, simulator, start: Trajectory, measured: MeasuredColumn, design_names=DESIGN_NAMES,
                 runout: RunoutMethod | None = None, temperature: float | None = None, checkpoint: bool = True,
                 segment_steps: int = SEGMENT_STEPS):
        config = simulator.config
        self.simulator = simulator
        self.measured = measured
        self.runout_method = RunoutMethod.from_config(runout)
        self.design_names = list(design_names)
        self.temperature = temperature
        self.checkpoint = checkpoint
        self.segment_steps = int(segment_steps)
        unknown = [n for n in self.design_names if n not in config.parameter_names]
        if unknown:
            raise InverseDesignError(f"design parameter(s) {unknown} are not inputs of the GNS "
                                     f"(it takes {config.parameter_names})")
        if not math.isclose(float(start.attrs["dt_frame"]), config.dt_frame, rel_tol=1e-9):
            raise InverseDesignError(f"start trajectory: dt_frame {start.attrs['dt_frame']} s differs from the "
                                     f"GNS's {config.dt_frame} s (one GNS step is one frame)")
        self.t_star = float(start.attrs["t_star"])
        self.L_i = float(start.attrs["L_i"])
        self.dt_frame = config.dt_frame
        if start.n_frames < config.n_input_frames:
            raise InverseDesignError(f"start trajectory has {start.n_frames} frames; the GNS needs C = "
                                     f"{config.n_input_frames} to start from")
        self.n_frames = frames_needed(measured.t_over_tstar, self.t_star, self.dt_frame)   # frames the runout reads
        self.n_steps = max(self.n_frames - config.n_input_frames, 0)
        dtype = simulator.bounds.dtype
        device = simulator.bounds.device
        self.initial = torch.as_tensor(start.positions[: config.n_input_frames], dtype=dtype, device=device)
        self.radius = torch.as_tensor(start.radius, dtype=dtype, device=device)
        self.particle_type = torch.as_tensor(start.particle_type, dtype=torch.long, device=device)
        self.fixed = torch.tensor([float(start.attrs[n]) for n in config.parameter_names], dtype=dtype, device=device)
        self.layout = torch.tensor([self.L_i, float(start.attrs["H_i"])], dtype=dtype, device=device)
        self.design_index = [config.parameter_names.index(n) for n in self.design_names]
        self.target = torch.as_tensor(measured.runout, dtype=dtype, device=device)
        self.n_particles = start.n_particles
        # where the online time goes: rollouts (graphs rolled out), forward and backward seconds
        self.timing = {"rollouts": 0, "forward_s": 0.0, "backward_s": 0.0}
        self._runouts: dict[tuple, np.ndarray] = {}      # L* [K] of every point rolled out, by its bytes

    def _context(self, theta: torch.Tensor):
        from gns.simulator import Context

        g, n = theta.shape[0], self.n_particles
        parameters = self.fixed.repeat(g, 1)
        parameters = parameters.index_copy(1, torch.tensor(self.design_index, device=theta.device), theta)
        return Context(self.particle_type.repeat(g), self.radius.repeat(g), parameters, self.layout.repeat(g, 1),
                       torch.arange(g, device=theta.device).repeat_interleave(n))

    def runout(self, theta: torch.Tensor) -> torch.Tensor:
        """L* [G, K] at the measured t/t* for theta [G, P] (differentiable when theta requires grad)."""
        from gns.rollout import RolloutError

        g, n = theta.shape[0], self.n_particles
        t0 = time.perf_counter()
        try:
            positions = self._rollout(theta)
        except (RolloutError, ValueError) as exc:
            raise InverseDesignError(f"GNS rollout at {self._describe(theta)} failed: {exc}") from None
        positions = positions.reshape(positions.shape[0], g, n, 2)
        try:     # a rollout spread too thin has no front by the configured rule
            runout = torch.stack([soft_runout_at(positions[:, j], self.radius, self.L_i, self.t_star, self.dt_frame,
                                                 self.measured.t_over_tstar, self.runout_method, self.temperature)
                                  for j in range(g)])
        except RunoutError as exc:
            raise InverseDesignError(f"GNS rollout at {self._describe(theta)} has no runout: {exc}") from None
        self.timing["rollouts"] += g
        self.timing["forward_s"] += time.perf_counter() - t0
        return runout

    def _segment(self, window: torch.Tensor, theta: torch.Tensor, n_steps: int) -> torch.Tensor:
        """The n_steps frames [n_steps, G N, 2] after the C frames `window` [C, G N, 2]."""
        from gns.rollout import rollout

        result = rollout(self.simulator, window, self._context(theta), n_steps, checkpoint=False)
        return result.positions[window.shape[0]:]

    def _rollout(self, theta: torch.Tensor) -> torch.Tensor:
        """Positions [C + n_steps, G N, 2] for theta [G, P].

        With a gradient to take, the rollout runs in segments of segment_steps steps, each under a
        (reentrant) checkpoint: the forward pass runs without autograd bookkeeping (as fast as a
        no-grad rollout) and keeps only each segment's first C frames; backward recomputes one
        segment at a time with autograd. Memory: one segment's activations (~40 MB per step per
        589-grain graph) instead of the whole rollout's. The gradient is the same as without
        checkpoints (tests/test_inverse.py)."""
        initial = self.initial.repeat(1, theta.shape[0], 1)
        if not (self.checkpoint and torch.is_grad_enabled() and theta.requires_grad):
            return torch.cat([initial, self._segment(initial, theta, self.n_steps)])
        from torch.utils.checkpoint import checkpoint

        frames, window, done = [initial], initial, 0
        c = initial.shape[0]
        while done < self.n_steps:
            steps = min(self.segment_steps, self.n_steps - done)
            new = checkpoint(self._segment, window, theta, steps, use_reentrant=True)
            frames.append(new)
            window = torch.cat([window, new])[-c:]
            done += steps
        return torch.cat(frames)

    def _describe(self, theta) -> str:
        rows = np.atleast_2d(theta.detach().cpu().numpy() if torch.is_tensor(theta) else theta)
        return "; ".join(", ".join(f"{n}={v:.4g}" for n, v in zip(self.design_names, row)) for row in rows)

    def _theta(self, points, requires_grad=False) -> torch.Tensor:
        theta = torch.as_tensor(np.atleast_2d(np.asarray(points, np.float64)), dtype=self.simulator.bounds.dtype,
                                device=self.simulator.bounds.device)
        return theta.clone().requires_grad_(requires_grad)

    def _checked(self, values: np.ndarray, points) -> np.ndarray:
        if not np.all(np.isfinite(values)):
            bad = np.atleast_2d(points)[~np.isfinite(values)]
            raise InverseDesignError(f"GNS objective is not finite at {self._describe(bad)}: no optimum from it")
        return values

    def _key(self, point) -> bytes:
        """A point as the model sees it (its dtype), so a cached runout is the one a rollout would give."""
        return self._theta(point).cpu().numpy().tobytes()

    def runout_values(self, points) -> np.ndarray:
        """L* [G, K] (numpy, no gradient) at points [G, P]; points rolled out before are not rolled
        out again (a rollout is deterministic)."""
        points = np.atleast_2d(np.asarray(points, np.float64))
        missing = [j for j, p in enumerate(points) if self._key(p) not in self._runouts]
        if missing:
            with torch.no_grad():
                fresh = self.runout(self._theta(points[missing])).double().cpu().numpy()
            self._runouts.update((self._key(points[j]), r) for j, r in zip(missing, fresh))
        return np.array([self._runouts[self._key(p)] for p in points])

    def values(self, points) -> np.ndarray:
        """Objective [G] at points [G, P], no gradient."""
        runout = self.runout_values(points)
        return self._checked(np.array([runout_mse(r, self.measured.runout) for r in runout]), points)

    def values_and_gradients(self, points) -> tuple[np.ndarray, np.ndarray]:
        """(objective [G], d objective / d theta [G, P]) by backpropagation through the rollout."""
        theta = self._theta(points, requires_grad=True)
        with torch.enable_grad():
            runout = self.runout(theta)
            values = torch.stack([runout_mse(r, self.target) for r in runout])
            self._runouts.update((self._key(p), r) for p, r in zip(np.atleast_2d(points),
                                                                    runout.detach().double().cpu().numpy()))
            t0 = time.perf_counter()
            values.sum().backward()          # graphs are independent: row g of the gradient is d value_g
            self.timing["backward_s"] += time.perf_counter() - t0
        values = self._checked(values.detach().double().cpu().numpy(), points)
        gradients = theta.grad.double().cpu().numpy()
        if not np.all(np.isfinite(gradients)):
            raise InverseDesignError(f"GNS gradient is not finite at {self._describe(points)}")
        return values, gradients


# -- multi-start L-BFGS-B in lockstep --------------------------------------------------------------
@dataclass
class StartResult:
    """One L-BFGS-B run: its start, optimum, every evaluation and the accepted iterates."""

    start: list
    params: list
    value: float
    success: bool
    message: str
    n_iterations: int
    evaluations: OptimisationHistory
    iterates: list = field(default_factory=list)     # [(params [P], value)] after each iteration

    def to_dict(self) -> dict:
        return {"start": self.start, "params": self.params, "value": self.value, "success": self.success,
                "message": self.message, "n_iterations": self.n_iterations,
                "n_evaluations": len(self.evaluations.values), "evaluations": self.evaluations.to_dict(),
                "iterates": [{"params": list(p), "value": v} for p, v in self.iterates]}


class _Lockstep:
    """Runs one L-BFGS-B per start in its own thread; the points they request at the same time are
    evaluated together by `serve` in the calling thread (where torch runs). A run requests points
    [m, P] (a finite-difference stencil: m = P + 1) and gets m answers back."""

    def __init__(self, n_runs: int, evaluate_batch):
        self.evaluate_batch = evaluate_batch
        self.condition = threading.Condition()
        self.pending: dict[int, np.ndarray] = {}
        self.results: dict[int, object] = {}
        self.active = n_runs
        self.error: BaseException | None = None
        self.batches = 0

    def request(self, run: int, x: np.ndarray):
        with self.condition:
            if self.error is not None:
                raise self.error
            self.pending[run] = np.atleast_2d(np.array(x, float))
            self.condition.notify_all()
            while run not in self.results and self.error is None:
                self.condition.wait()
            if self.error is not None:
                raise self.error
            return self.results.pop(run)

    def finished(self):
        with self.condition:
            self.active -= 1
            self.condition.notify_all()

    def serve(self):
        while True:
            with self.condition:
                while len(self.pending) < self.active and self.error is None:
                    self.condition.wait()
                if self.error is not None or (self.active == 0 and not self.pending):
                    return
                batch = dict(sorted(self.pending.items()))
                self.pending.clear()
            try:
                answers = self.evaluate_batch(np.concatenate(list(batch.values())))
            except BaseException as exc:  # noqa: BLE001 - handed to every waiting run, then re-raised
                with self.condition:
                    self.error = exc
                    self.condition.notify_all()
                raise
            self.batches += 1
            with self.condition:
                ends = np.cumsum([len(points) for points in batch.values()])
                self.results.update((run, answers[end - len(points):end])
                                    for (run, points), end in zip(batch.items(), ends))
                self.condition.notify_all()


def multistart_lbfgsb(evaluate_batch, starts, bounds, names, gradient: str = "autograd", fd_step: float = FD_STEP,
                      max_iterations: int = 20, ftol: float = FTOL, gtol: float = GTOL, progress=None,
                      max_evaluations: int | None = None) -> tuple[list, int]:
    """L-BFGS-B from each of starts [S, P] within bounds [(low, high)] * P, in lockstep.

    evaluate_batch(points [G, P]) -> (values [G], gradients [G, P]) for gradient="autograd", or
    values [G] for gradient="finite-difference": forward differences with step fd_step (the paper's
    eq. (8), as scipy's with eps = fd_step: a step that would leave the bounds goes backwards), the
    P + 1 points of each stencil evaluated in one batch instead of one after another. ftol, gtol:
    scipy's stopping tests; max_evaluations: scipy's maxfun, evaluations of objective and gradient
    per start (default 2 max_iterations), which bounds the time a start can spend retrying line
    searches on a rough objective.
    progress: callable(batch number, seconds, values) or None.
    Returns ([StartResult] in start order, number of batches evaluated).
    """
    if gradient not in GRADIENTS:
        raise ValueError(f"gradient must be one of {GRADIENTS}, got {gradient!r}")
    starts = np.atleast_2d(np.asarray(starts, float))
    bounds = [tuple(map(float, b)) for b in bounds]
    for start in starts:
        for value, (low, high), name in zip(start, bounds, names):
            if not low <= value <= high:
                raise InverseDesignError(f"start {name} = {value:g} lies outside the bounds [{low:g}, {high:g}]")
    use_gradient = gradient == "autograd"
    if not use_gradient:
        check_step(fd_step, bounds)
    histories = [OptimisationHistory(names=list(names)) for _ in starts]
    iterates = [[] for _ in starts]

    def timed_batch(points):
        t0 = time.perf_counter()
        answer = evaluate_batch(points)
        seconds = time.perf_counter() - t0
        values = answer[0] if use_gradient else answer
        if progress is not None:
            progress(lockstep.batches + 1, seconds, values)
        per_point = seconds / len(points)
        return [((values[j], answer[1][j]) if use_gradient else values[j], per_point) for j in range(len(points))]

    lockstep = _Lockstep(len(starts), timed_batch)
    outcomes: list = [None] * len(starts)

    def run(index):
        stall = {"best": math.inf, "count": 0}

        def check_stall(value):
            if math.isinf(stall["best"]) or value < stall["best"] - ftol * max(abs(stall["best"]), 1.0):
                stall["count"] = 0
            else:
                stall["count"] += 1
            stall["best"] = min(stall["best"], value)
            if stall["count"] >= STALL_EVALUATIONS:
                raise _Stalled

        def fun(x):
            if use_gradient:
                ((answer, seconds),) = lockstep.request(index, x)
                histories[index].record(x, answer[0], seconds)
                check_stall(float(answer[0]))
                return float(answer[0]), np.asarray(answer[1], float)
            steps = np.array([fd_step if x[j] + fd_step <= bounds[j][1] else -fd_step for j in range(len(x))])
            stencil = np.vstack([x, x + np.diag(steps)])
            answers = lockstep.request(index, stencil)
            value = float(answers[0][0])
            histories[index].record(x, value, sum(seconds for _, seconds in answers))
            check_stall(value)
            # the step as represented (x + h) - x, as scipy's approx_derivative takes it
            gradient_fd = [(float(answers[j + 1][0]) - value) / (stencil[j + 1][j] - x[j]) for j in range(len(x))]
            return value, np.array(gradient_fd)

        def callback(intermediate_result):
            iterates[index].append((intermediate_result.x.tolist(), float(intermediate_result.fun)))

        try:
            options = {"maxiter": max_iterations, "ftol": ftol, "gtol": gtol, "maxls": MAX_LINE_SEARCH,
                       "maxfun": max_evaluations or 2 * max_iterations}
            outcomes[index] = minimize(fun, starts[index], method="L-BFGS-B", jac=True, bounds=bounds,
                                       options=options, callback=callback)
        except _Stalled:
            params, value = histories[index].best
            outcomes[index] = OptimizeResult(x=np.asarray(params), fun=value, success=False, nit=len(iterates[index]),
                                             message=f"stopped: {STALL_EVALUATIONS} evaluations in a row without "
                                                     "improvement (rough objective)")
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            outcomes[index] = exc
        finally:
            lockstep.finished()

    threads = [threading.Thread(target=run, args=(k,), daemon=True) for k in range(len(starts))]
    for thread in threads:
        thread.start()
    try:
        lockstep.serve()
    finally:
        for thread in threads:
            thread.join()
    results = []
    for k, outcome in enumerate(outcomes):
        if isinstance(outcome, BaseException):
            raise outcome
        # a line search that fails on a rough objective ends at its last accepted iterate, which may
        # be worse than a point it tried: keep the best point evaluated, and say so
        params, value = histories[k].best
        message = str(outcome.message)
        if value < float(outcome.fun):
            message += f"; best evaluated point kept (L-BFGS-B ended at {float(outcome.fun):.4g})"
        else:
            params, value = outcome.x, float(outcome.fun)
        results.append(StartResult(start=starts[k].tolist(), params=np.asarray(params).tolist(), value=float(value),
                                   success=bool(outcome.success), message=message,
                                   n_iterations=int(outcome.nit), evaluations=histories[k],
                                   iterates=[(starts[k].tolist(), histories[k].values[0])] + iterates[k]))
    return results, lockstep.batches


def starting_points(n_starts: int, bounds, first=PAPER_START, seed: int = 0) -> np.ndarray:
    """[n_starts, P]: `first` (the paper's start), then a seeded Latin hypercube over the bounds."""
    from scipy.stats import qmc

    bounds = np.asarray(bounds, float)
    points = [np.clip(np.asarray(first, float), bounds[:, 0], bounds[:, 1])]
    if n_starts > 1:
        unit = qmc.LatinHypercube(d=len(bounds), seed=seed).random(n_starts - 1)
        points += list(bounds[:, 0] + unit * (bounds[:, 1] - bounds[:, 0]))
    return np.array(points[:n_starts])


def check_bounds(bounds, names, parameter_ranges: dict) -> list[tuple[float, float]]:
    """The bounds as floats; InverseDesignError when one leaves the range the GNS was trained on."""
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
                f"inverse.{name}) or train on a wider range")
    return bounds


def design_bounds(bounds, names, parameter_ranges: dict) -> list[tuple[float, float]]:
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
@dataclass
class InverseResult:
    """Everything an inverse design produced (JSON via to_dict)."""

    measured: str
    names: list
    bounds: list
    gradient: str
    starts: list                      # [StartResult]
    best_params: list
    best_value: float
    best_runout: list                 # GNS L* at the measured t/t* at the optimum
    start_runout: list                # GNS L* at the first start
    posterior: dict
    geometry: dict
    seconds: dict                     # optimisation, posterior, total (online), landscape
    n_batches: int
    landscape: dict | None = None     # {"axes": [[...], [...]], "values": [[...]]} GNS objective grid
    model_error_std: float | None = None  # GNS runout error (L*) joined to the noise model
    roughness: dict | None = None     # objective near the optimum (see posterior_at)
    start_packing_std: list | None = None  # packing scatter of L* [K] joined to the noise model
    runout: dict | None = None        # the runout method (dem.runout.RunoutMethod.to_config) every L* was read by

    def to_dict(self) -> dict:
        data = {k: getattr(self, k) for k in ("measured", "names", "bounds", "gradient", "best_params", "best_value",
                                              "best_runout", "start_runout", "posterior", "geometry", "seconds",
                                              "n_batches", "landscape", "model_error_std", "roughness",
                                              "start_packing_std", "runout")}
        data["starts"] = [s.to_dict() for s in self.starts]
        return data


def noise_level(measured: MeasuredColumn, model_error_std: float | None, start_packing_std=None):
    """Noise std [K] of the posterior, or None (estimate from residuals) when the data give none.

    The surrogate's own error (RMS of GNS - DEM L*, scalar) and the scatter of one packing's runout
    (start_packing_std, [K] or scalar, L*: every rollout starts from one packing, so the GNS
    predicts one packing's curve, not the mean over packings) add to the measured noise in
    quadrature: the posterior is of the DEM parameters, seen through an imperfect surrogate that
    runs one random packing.
    """
    if measured.runout_std is None:
        return None
    packing = 0.0 if start_packing_std is None else np.asarray(start_packing_std, float)
    return np.sqrt(np.asarray(measured.runout_std, float) ** 2 + (model_error_std or 0.0) ** 2 + packing ** 2)


def posterior_at(objective: GNSObjective, optimum, bounds, model_error_std=None, step: float = JACOBIAN_STEP,
                 start_packing_std=None):
    """Laplace posterior (calibration.uncertainty) at `optimum` from a central-difference Jacobian of
    the GNS's L*, and a roughness probe: the objective ROUGHNESS_RADIUS away in ROUGHNESS_PROBES
    directions. All
    rollouts run as one batch. Returns (LaplacePosterior, L* [K] at the optimum, roughness dict:
    radius, values, optimum value and their spread, to set against the posterior's step)."""
    optimum = np.asarray(optimum, float)
    points = []
    finite_difference_jacobian(lambda theta: points.append(np.array(theta)) or np.zeros(1), optimum, bounds, step)
    low, high = np.asarray(bounds, float).T
    angles = np.pi / 4 + np.arange(ROUGHNESS_PROBES) * 2 * np.pi / ROUGHNESS_PROBES
    probes = [np.clip(optimum + ROUGHNESS_RADIUS * np.array([np.cos(a), np.sin(a)]), low, high) for a in angles]
    runouts = objective.runout_values(np.vstack([optimum] + points + probes))
    replay = iter(runouts[1:1 + len(points)])
    jacobian = finite_difference_jacobian(lambda theta: next(replay), optimum, bounds, step)
    residuals = runouts[0] - objective.measured.runout
    posterior = laplace_posterior(objective.design_names, optimum, jacobian, residuals, bounds,
                                  sigma=noise_level(objective.measured, model_error_std, start_packing_std))
    values = [runout_mse(r, objective.measured.runout) for r in runouts]
    probe_values = values[1 + len(points):]
    roughness = {"radius": ROUGHNESS_RADIUS, "values": probe_values, "optimum_value": values[0],
                 "spread": float(np.max(probe_values + values[:1]) - np.min(probe_values + values[:1])),
                 "jacobian_step": step, "jacobian_step_values": values[1:1 + len(points)]}
    return posterior, runouts[0], roughness


def landscape(objective: GNSObjective, bounds, levels: int, batch_size: int = 8) -> dict:
    """The GNS objective on a levels x levels grid over two design parameters (batched, no grad)."""
    axes = [np.linspace(low, high, levels) for low, high in bounds]
    grid = np.array([(a, b) for b in axes[1] for a in axes[0]])
    values = np.concatenate([objective.values(grid[k:k + batch_size]) for k in range(0, len(grid), batch_size)])
    return {"axes": [a.tolist() for a in axes], "values": values.reshape(levels, levels).tolist()}


def inverse_design(simulator, start: Trajectory, measured: MeasuredColumn, metadata: dict, training_attrs: list[dict],
                   bounds=None, n_starts: int = 4, first_start=PAPER_START, gradient: str = "autograd",
                   fd_step: float = FD_STEP, max_iterations: int = 20, ftol: float = FTOL, gtol: float = GTOL,
                   max_evaluations: int | None = None, model_error_std: float | None = None,
                   landscape_levels: int = 0, seed: int = 0, start_packing_std=None,
                   design_names=DESIGN_NAMES, runout: RunoutMethod | None = None) -> InverseResult:
    """Calibrate design_names against `measured` through the GNS `simulator`.

    start: DEM trajectory of the measured column giving the first C frames (see GNSObjective);
    metadata: the GNS dataset's metadata; training_attrs: attributes of its training trajectories
    (for the geometry check). bounds: [(low, high) or None] per design parameter (see design_bounds).
    model_error_std, start_packing_std: the posterior's model-side noise (see noise_level).
    runout: how L* is read (dem.runout.RunoutMethod; None: its default).
    Returns an InverseResult; seconds["online"] is the wall time of the
    optimisation and the posterior (the landscape, a figure, is timed apart).
    """
    names = list(design_names)
    bounds = design_bounds(bounds, names, metadata["parameter_ranges"])
    geometry = check_geometry(measured, metadata, training_attrs)
    runout = RunoutMethod.from_config(runout)
    objective = GNSObjective(simulator, start, measured, names, runout=runout)
    starts = starting_points(n_starts, bounds, first_start, seed)
    log.info("inverse design of %s: %d starts, %s gradients, %d rollout steps of %d grains", measured.name,
             len(starts), gradient, objective.n_steps, objective.n_particles)

    def evaluate(points):
        return objective.values_and_gradients(points) if gradient == "autograd" else objective.values(points)

    def progress(batch, seconds, values):
        log.info("batch %d: %d rollouts in %.1f s, objective %s", batch, len(values), seconds,
                 " ".join(f"{v:.4g}" for v in values))

    t0 = time.perf_counter()
    runs, n_batches = multistart_lbfgsb(evaluate, starts, bounds, names, gradient, fd_step, max_iterations,
                                        ftol, gtol, progress, max_evaluations)
    t1 = time.perf_counter()
    best = min(runs, key=lambda r: r.value)
    posterior, best_runout, roughness = posterior_at(objective, best.params, bounds, model_error_std,
                                                     start_packing_std=start_packing_std)
    t2 = time.perf_counter()
    online = dict(objective.timing)          # where the online time went: rollouts, forward, backward
    start_runout = objective.runout_values(starts[:1])[0]
    grid = landscape(objective, bounds, landscape_levels) if landscape_levels else None
    t3 = time.perf_counter()
    for p in posterior.parameters:
        log.info("%s = %.4f, 95%% interval [%.4f, %.4f]%s", p.name, p.value, p.low, p.high,
                 "" if p.identifiable else f" NOT identifiable: {p.why}")
    return InverseResult(measured=measured.name, names=names, bounds=[list(b) for b in bounds], gradient=gradient,
                         starts=runs, best_params=list(best.params), best_value=best.value,
                         best_runout=best_runout.tolist(), start_runout=start_runout.tolist(),
                         posterior=posterior.to_dict(), geometry=geometry,
                         seconds={"optimisation": t1 - t0, "posterior": t2 - t1, "online": t2 - t0,
                                  "landscape": t3 - t2, "online_forward": online["forward_s"],
                                  "online_backward": online["backward_s"], "online_rollouts": online["rollouts"],
                                  "rollout_steps": objective.n_steps},
                         n_batches=n_batches, landscape=grid, model_error_std=model_error_std,
                         roughness=roughness, start_packing_std=None if start_packing_std is None else
                         np.broadcast_to(start_packing_std, measured.runout.shape).tolist(),
                         runout=runout.to_config())


# -- outputs ----------------------------------------------------------------------------------------
def write_result(result: InverseResult, path) -> None:
    """inverse.json (atomically)."""
    import json

    from dem.atomic import write_text

    write_text(path, json.dumps(result.to_dict(), indent=1) + "\n")


def read_result(path) -> dict:
    import json
    from pathlib import Path

    return json.loads(Path(path).read_text())


def _ellipse(ax, centre, covariance, colour="w"):
    """95% credible ellipse of a 2-parameter Gaussian posterior."""
    from matplotlib.patches import Ellipse
    from scipy.stats import chi2

    values, vectors = np.linalg.eigh(np.asarray(covariance, float))
    scale = math.sqrt(chi2.ppf(0.95, 2))
    width, height = 2 * scale * np.sqrt(np.maximum(values, 0))
    angle = math.degrees(math.atan2(vectors[1, 1], vectors[0, 1]))
    ax.add_patch(Ellipse(centre, height, width, angle=angle, fill=False, ec=colour, lw=1.2, ls="--",
                         label="95% credible region"))


def plot_paths(result: dict, path, dem_points=None, title: str = "") -> None:
    """The optimisation paths of every start over the objective landscape (the paper's Fig. 2).

    result: InverseResult.to_dict(); its GNS landscape (if computed) is the background. dem_points:
    optional DEM objective values {"friction": [...], "restitution": [...], "mse": [...]} (e.g. the
    DoE runs), drawn as squares coloured on the same scale. The posterior's 95% region is dashed.
    """
    from dem.plots import plt, save_figure

    names = result["names"]
    (x_low, x_high), (y_low, y_high) = result["bounds"]
    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    values = [v for s in result["starts"] for v in s["evaluations"]["values"]]
    if dem_points is not None:
        values += list(dem_points["mse"])
    grid = result.get("landscape")
    if grid:
        values += [v for row in grid["values"] for v in row]
    finite = np.array([v for v in values if np.isfinite(v)])
    norm = plt.matplotlib.colors.LogNorm(max(finite.min(), 1e-4), max(finite.max(), 1e-3))
    if grid:
        shade = ax.contourf(grid["axes"][0], grid["axes"][1], np.maximum(grid["values"], norm.vmin),
                            levels=np.geomspace(norm.vmin, norm.vmax, 16), norm=norm, cmap="viridis")
        fig.colorbar(shade, ax=ax, label="objective (runout MSE), GNS landscape")
    if dem_points is not None:
        dots = ax.scatter(dem_points[names[0]], dem_points[names[1]], c=np.maximum(dem_points["mse"], norm.vmin),
                          norm=norm, cmap="viridis", marker="s", s=40, edgecolors="0.3", label="DEM runs (DoE)")
        if not grid:
            fig.colorbar(dots, ax=ax, label="objective (runout MSE), DEM")
    for k, start in enumerate(result["starts"]):
        points = np.array([p["params"] for p in start["iterates"]])
        colour = plt.get_cmap("tab10")(k % 10)
        ax.plot(points[:, 0], points[:, 1], "-", color=colour, lw=1.2)
        for a, b in zip(points[:-1], points[1:]):
            ax.annotate("", b, a, arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.2})
        ax.plot(*points[0], "o", color="k", ms=6, zorder=4)
        ax.plot(*points[-1], "o", color=colour, mec="k", ms=6, zorder=4,
                label=f"start {k + 1}: {start['iterates'][0]['value']:.3g} -> {start['value']:.3g}")
    best = result["best_params"]
    ax.plot(*best, "r*", ms=16, mec="w", zorder=5, label=f"optimum ({best[0]:.3f}, {best[1]:.3f})")
    _ellipse(ax, best, result["posterior"]["covariance"], colour="r")
    if dem_points is not None:      # the DEM runs may lie beyond the GNS's (trained-range) bounds
        x_low, x_high = min(x_low, np.min(dem_points[names[0]])), max(x_high, np.max(dem_points[names[0]]))
        y_low, y_high = min(y_low, np.min(dem_points[names[1]])), max(y_high, np.max(dem_points[names[1]]))
        ax.add_patch(plt.Rectangle((result["bounds"][0][0], result["bounds"][1][0]),
                                   np.diff(result["bounds"][0])[0], np.diff(result["bounds"][1])[0], fill=False,
                                   ec="0.4", ls=":", lw=1, label="GNS bounds"))
    pad = 0.02
    ax.set(xlim=(x_low - pad, x_high + pad), ylim=(y_low - pad, y_high + pad), xlabel=f"{names[0]}", ylabel=f"{names[1]}",
           title=title or f"GNS inverse design of {result['measured']} ({result['gradient']} gradients)")
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    save_figure(fig, path)


def plot_deposits(objective: GNSObjective, params: dict, path, title: str = "") -> None:
    """GNS deposits at the last measured t/t* for each labelled parameter set (the paper's Fig. 9):
    params {label: [P]}; the measured final runout is the dashed line."""
    from dem.plots import draw_grains, plt, save_figure

    labels = list(params)
    theta = objective._theta(np.array([params[k] for k in labels]))
    from gns.rollout import rollout
    from gns.runout import frame_weights

    with torch.no_grad():
        result = rollout(objective.simulator, objective.initial.repeat(1, len(labels), 1), objective._context(theta),
                         objective.n_steps, checkpoint=False)
    t_last = float(objective.measured.t_over_tstar[-1])
    k, w = frame_weights([t_last], objective.t_star, objective.dt_frame, result.positions.shape[0])[0]
    frame = int(k + round(w))
    positions = result.positions[frame].reshape(len(labels), objective.n_particles, 2).cpu().numpy()
    radius = objective.radius.cpu().numpy()
    measured_front = objective.L_i * (1 + float(objective.measured.runout[-1]))
    extent = max(float(positions[..., 0].max()), measured_front) * 1.1
    height = float(objective.initial[0, :, 1].max()) * 0.6 + 4 * float(radius.max())
    fig, axes = plt.subplots(len(labels), 1, figsize=(8, 1.2 + 1.3 * len(labels)), squeeze=False)
    for ax, label, frame_positions in zip(axes[:, 0], labels, positions):
        draw_grains(ax, frame_positions, radius, color="tab:blue")
        ax.axvline(measured_front, color="0.4", ls="--", lw=1, label=f"measured L* = {objective.measured.runout[-1]:.3g}")
        ax.axvline(objective.L_i, color="0.7", ls=":", lw=0.8)
        ax.set(xlim=(0, extent), ylim=(0, height), aspect="equal")
        ax.set_title(f"{label}: " + ", ".join(f"{n} = {v:.3f}" for n, v in zip(objective.design_names, params[label]))
                     + f"  (t/t* = {frame * objective.dt_frame / objective.t_star:.2f})", fontsize=8, loc="left")
        ax.tick_params(labelsize=6)
    axes[0, 0].legend(fontsize=7, loc="upper right")
    fig.suptitle(title or f"GNS deposits during the inverse design of {objective.measured.name}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
