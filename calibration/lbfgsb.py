"""Multi-start L-BFGS-B in lockstep: the optimiser of the GNS inverse design (calibration.inverse).

scipy's L-BFGS-B moves the design parameters within bounds. Gradients come either with the
objective (automatic differentiation through the rollout, calibration.gns_objective), or from
forward differences as in the paper's eq. (8) -- with a step the float32 model resolves: scipy's
default 1e-8 vanishes in float32 (0.31 + 1e-8 == 0.31), so the differences are exactly zero and
L-BFGS-B stops at its start.

Several starts run in lockstep: each is its own L-BFGS-B (its path is the one a lone run would
take), and the points they ask for at the same moment are rolled out together (GNSObjective batches); with
finite differences each start asks for its whole stencil (x and x + h e_j) at once.

A GNS objective is rough (calibration.gns_objective), so line searches may fail; each start keeps
its best evaluated point and says so. A point where the objective is not finite (NaN or inf: a GNS
rollout that diverged there) is a failed point: it is recorded in the start's history with the
reason, and that start ends at its best point so far while the others go on; only when no point of
any start could be evaluated is it an error.

The call and its result are those of every optimiser here (calibration.optimise).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, DTypeLike
from scipy.optimize import OptimizeResult, minimize

from calibration.geometry import InverseDesignError
from calibration.optimise import BatchObjective, OptimisationHistory, OptimisationResult, Progress

PAPER_START = (0.55, 0.73)  # the paper's starting point (Fig. 2, loss 0.66)
SCIPY_DEFAULT_STEP = 1e-8  # scipy's L-BFGS-B `eps`, the step of the paper's public code
# Forward-difference step for the float32 GNS. The rounding error of a float32 objective is
# ~1e-7 relative, so a step h gives a gradient error ~1e-7 / h; the radius graph also switches
# edges on and off, which puts small jumps in the objective. 1e-2 (1.7% of the [0.3, 0.9] range)
# averages over both and still resolves the curvature of the runout (tests/test_inverse.py).
FD_STEP = 1e-2
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


class _Failed(Exception):
    """The objective was not finite at a start's point (e.g. a GNS rollout that diverged there)."""


# -- float32 resolution -----------------------------------------------------------------------------
def step_vanishes(value: float, step: float, dtype: DTypeLike = np.float32) -> bool:
    """True when value + step rounds back to value in `dtype` (the FD difference is then zero)."""
    return bool(dtype(value) + dtype(step) == dtype(value))


def check_step(step: float, bounds: Sequence[Sequence[float]], dtype: DTypeLike = np.float32) -> None:
    """InverseDesignError when a finite-difference step vanishes somewhere in bounds [(low, high)] * P."""
    for low, high in bounds:
        for value in (low, high, 0.5 * (low + high)):
            if step_vanishes(value, step, dtype):
                raise InverseDesignError(
                    f"finite-difference step {step:g} vanishes in {np.dtype(dtype).name} at {value:g} "
                    f"({value:g} + {step:g} == {value:g}): the differences would be exactly zero; "
                    f"use a step above {np.spacing(dtype(high)):.2g} (default {FD_STEP:g})"
                )


# -- multi-start L-BFGS-B in lockstep --------------------------------------------------------------
@dataclass
class LBFGSBSettings:
    """starts [S, P]: one L-BFGS-B from each (starting_points). gradient: "autograd" (the objective
    returns (values [G], gradients [G, P])) or "finite-difference" (values [G]; forward differences
    of step fd_step, in parameter units). max_iterations, ftol, gtol: scipy's maxiter and stopping
    tests; max_evaluations: scipy's maxfun per start (None: 2 max_iterations)."""

    starts: ArrayLike
    gradient: str = "autograd"
    fd_step: float = FD_STEP
    max_iterations: int = 20
    ftol: float = FTOL
    gtol: float = GTOL
    max_evaluations: int | None = None
    # [P] units L-BFGS-B steps in (x / scale): parameters whose ranges differ by orders of magnitude
    # (friction in [0.3, 0.9], a Bond number in [0, 60]) would otherwise get one step length for all
    scale: ArrayLike | None = None


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
    iterates: list = field(default_factory=list)  # [(params [P], value)] after each iteration

    def to_dict(self) -> dict:
        """JSON of the start (inverse.json's "starts"): evaluations as OptimisationHistory.to_dict."""
        return {
            "start": self.start,
            "params": self.params,
            "value": self.value,
            "success": self.success,
            "message": self.message,
            "n_iterations": self.n_iterations,
            "n_evaluations": len(self.evaluations.values),
            "evaluations": self.evaluations.to_dict(),
            "iterates": [{"params": list(p), "value": v} for p, v in self.iterates],
        }


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

    def request(self, run: int, x: np.ndarray) -> list:
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

    def finished(self) -> None:
        with self.condition:
            self.active -= 1
            self.condition.notify_all()

    def serve(self) -> None:
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
                self.results.update(
                    (run, answers[end - len(points) : end]) for (run, points), end in zip(batch.items(), ends)
                )
                self.condition.notify_all()


def multistart_lbfgsb(
    evaluate_batch: BatchObjective,
    bounds: Sequence[Sequence[float]],
    names: Sequence[str],
    settings: LBFGSBSettings,
    progress: Progress | None = None,
) -> OptimisationResult:
    """L-BFGS-B from each of settings.starts [S, P] within bounds [(low, high)] * P, in lockstep
    (the calibration.optimise.Optimiser call).

    evaluate_batch(points [G, P]) -> (values [G], gradients [G, P]) for gradient="autograd", or
    values [G] for gradient="finite-difference": forward differences with step fd_step (the paper's
    eq. (8), as scipy's with eps = fd_step: a step that would leave the bounds goes backwards), the
    P + 1 points of each stencil evaluated in one call instead of one after another.
    max_evaluations bounds the time a start can spend retrying line searches on a rough objective.
    progress: callable(batch number, seconds, values [G]) or None.
    Returns the best of the starts, the history of every start's evaluations (start k's labelled k,
    each with the iterations that start had completed; the stencil's other points are not recorded,
    their time is; the failed points with their reason), its StartResult per start (in start order;
    a start whose first point failed has none) and the number of batches evaluated.
    """
    starts, gradient, fd_step = settings.starts, settings.gradient, settings.fd_step
    max_iterations, ftol, gtol = settings.max_iterations, settings.ftol, settings.gtol
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
    scale = np.ones(starts.shape[1]) if settings.scale is None else np.asarray(settings.scale, float)

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

        def failed(x, answers, seconds):
            """Record x as failed and end the start when any of its answers is not finite."""
            if all(np.all(np.isfinite(a)) for a in answers):
                return
            reason = "objective not finite there" + (" (value or gradient)" if use_gradient else " (FD stencil)")
            histories[index].record_failure(x, reason, seconds, index, len(iterates[index]))
            raise _Failed(reason)

        def fun(z):
            x = z * scale
            if use_gradient:
                ((answer, seconds),) = lockstep.request(index, x)
                failed(x, answer, seconds)
                histories[index].record(x, answer[0], seconds, index, len(iterates[index]))
                check_stall(float(answer[0]))
                return float(answer[0]), np.asarray(answer[1], float) * scale
            steps = np.array([fd_step if x[j] + fd_step <= bounds[j][1] else -fd_step for j in range(len(x))])
            stencil = np.vstack([x, x + np.diag(steps)])
            answers = lockstep.request(index, stencil)
            failed(x, [a for a, _ in answers], sum(seconds for _, seconds in answers))
            value = float(answers[0][0])
            histories[index].record(x, value, sum(seconds for _, seconds in answers), index, len(iterates[index]))
            check_stall(value)
            # the step as represented (x + h) - x, as scipy's approx_derivative takes it
            gradient_fd = [(float(answers[j + 1][0]) - value) / (stencil[j + 1][j] - x[j]) for j in range(len(x))]
            return value, np.array(gradient_fd) * scale

        def callback(intermediate_result):
            iterates[index].append(((intermediate_result.x * scale).tolist(), float(intermediate_result.fun)))

        try:
            options = {
                "maxiter": max_iterations,
                "ftol": ftol,
                "gtol": gtol,
                "maxls": MAX_LINE_SEARCH,
                "maxfun": settings.max_evaluations or 2 * max_iterations,
            }
            outcomes[index] = minimize(
                fun,
                starts[index] / scale,
                method="L-BFGS-B",
                jac=True,
                bounds=[(low / s, high / s) for (low, high), s in zip(bounds, scale)],
                options=options,
                callback=callback,
            )
        except (_Stalled, _Failed) as exc:
            if not histories[index].values:  # failed at its start: nothing to keep
                outcomes[index] = None
                return
            params, value = histories[index].best
            why = (
                f"{STALL_EVALUATIONS} evaluations in a row without improvement (rough objective)"
                if isinstance(exc, _Stalled)
                else f"the objective at {np.round(histories[index].failed[-1]['params'], 4).tolist()} is not "
                "finite (a failed point, recorded)"
            )
            outcomes[index] = OptimizeResult(
                x=np.asarray(params) / scale,
                fun=value,
                success=False,
                nit=len(iterates[index]),
                message=f"stopped: {why}",
            )
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
        if outcome is None:  # its start point failed: in the history's failed points only
            continue
        # a line search that fails on a rough objective ends at its last accepted iterate, which may
        # be worse than a point it tried: keep the best point evaluated, and say so
        params, value = histories[k].best
        message = str(outcome.message)
        if value < float(outcome.fun):
            message += f"; best evaluated point kept (L-BFGS-B ended at {float(outcome.fun):.4g})"
        else:
            params, value = outcome.x * scale, float(outcome.fun)
        results.append(
            StartResult(
                start=starts[k].tolist(),
                params=np.asarray(params).tolist(),
                value=float(value),
                success=bool(outcome.success),
                message=message,
                n_iterations=int(outcome.nit),
                evaluations=histories[k],
                iterates=[(starts[k].tolist(), histories[k].values[0])] + iterates[k],
            )
        )
    history = OptimisationHistory.concatenate(histories)
    if not results:
        raise InverseDesignError(f"no start could be evaluated: {history.failures_text()}")
    best = min(results, key=lambda r: r.value)
    return OptimisationResult(
        params=best.params,
        value=best.value,
        history=history,
        n_batches=lockstep.batches,
        starts=results,
    )


def starting_points(
    n_starts: int, bounds: Sequence[Sequence[float]], first: Sequence[float] = PAPER_START, seed: int = 0
) -> np.ndarray:
    """[n_starts, P]: `first` (the paper's start), then a seeded Latin hypercube over the bounds."""
    from scipy.stats import qmc

    bounds = np.asarray(bounds, float)
    points = [np.clip(np.asarray(first, float), bounds[:, 0], bounds[:, 1])]
    if n_starts > 1:
        unit = qmc.LatinHypercube(d=len(bounds), seed=seed).random(n_starts - 1)
        points += list(bounds[:, 0] + unit * (bounds[:, 1] - bounds[:, 0]))
    return np.array(points[:n_starts])
