"""One interface for the optimisers of the calibration routes, and the one history they keep.

Every optimiser is a function of the same shape (the `Optimiser` protocol):

    optimiser(objective, bounds, names, settings, progress=None) -> OptimisationResult

- objective(points [G, P]) -> values [G]: a batch of parameter points in, one objective value each
  out (an L-BFGS-B asked for autograd gradients wants (values [G], gradients [G, P]));
  `one_at_a_time` makes one of a function of a single point;
- bounds [(low, high)] * P, names [P] (the parameters' names, in the history and in messages);
- settings: the optimiser's own dataclass (calibration.lbfgsb.LBFGSBSettings: lockstep multi-start
  L-BFGS-B; calibration.bayesopt.BOSettings: Bayesian optimisation);
- progress: callable(batch number, seconds of that batch, values [G]) after every objective call.

The result holds the best point found and an `OptimisationHistory` of every evaluation: its
parameters, value, wall time, and which start and iteration it belongs to.

An objective that cannot be evaluated at a point (its DEM run failed) raises `PointFailed` with
the reason. An optimiser that can do without the point (the Bayesian optimisation) records it in
the history's `failed` list, never gives it a value, and goes on; it raises OptimisationError when
no point could be evaluated. The others let PointFailed propagate.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

# objective(points [G, P]) -> values [G], or (values [G], gradients [G, P])
BatchObjective = Callable[[np.ndarray], Any]
# progress(batch number, seconds of the batch, values [G])
Progress = Callable[[int, float, np.ndarray], None]


class PointFailed(RuntimeError):
    """The objective cannot be evaluated at a point (e.g. its DEM run failed); the message says why."""


class OptimisationError(RuntimeError):
    """An optimiser could evaluate no point at all; the message lists each failure and its reason."""


@dataclass
class OptimisationHistory:
    """Every evaluation in order: params [n, p], values [n], wall time of each (s), and for each the
    start it belongs to (0 for a single-start optimiser) and the optimiser's iteration it was made
    in (L-BFGS-B: iterations the start had completed; Bayesian optimisation: 0 for the initial
    design, then k for the k-th point chosen by expected improvement). failed: the points the
    objective could not evaluate (PointFailed), each {params, reason, seconds, start, iteration};
    they have no value and take no part in `best`."""

    names: list
    params: list = field(default_factory=list)
    values: list = field(default_factory=list)
    seconds: list = field(default_factory=list)
    start: list = field(default_factory=list)
    iteration: list = field(default_factory=list)
    failed: list = field(default_factory=list)

    def record(self, params: Sequence[float], value: float, seconds: float, start: int = 0, iteration: int = 0) -> None:
        """Append one evaluation: params [p], its objective value, its wall time (s)."""
        self.params.append([float(p) for p in params])
        self.values.append(float(value))
        self.seconds.append(float(seconds))
        self.start.append(int(start))
        self.iteration.append(int(iteration))

    def record_failure(
        self, params: Sequence[float], reason: str, seconds: float, start: int = 0, iteration: int = 0
    ) -> None:
        """Append a point the objective could not evaluate, with the reason (PointFailed's message)."""
        self.failed.append(
            {
                "params": [float(p) for p in params],
                "reason": str(reason),
                "seconds": float(seconds),
                "start": int(start),
                "iteration": int(iteration),
            }
        )

    @property
    def n_calls(self) -> int:
        """Objective calls made: the points evaluated and those that failed."""
        return len(self.values) + len(self.failed)

    @property
    def best(self) -> tuple[np.ndarray, float]:
        """(params [p], value) of the lowest value (the first of equal ones)."""
        if not self.values:
            raise OptimisationError(
                f"no point of {self.names} was evaluated ({len(self.failed)} failed): {self.failures_text()}"
            )
        k = int(np.argmin(self.values))
        return np.array(self.params[k]), self.values[k]

    @classmethod
    def concatenate(cls, histories: Sequence[OptimisationHistory]) -> OptimisationHistory:
        """One history of the evaluations of `histories` (of the same parameters), one after another."""
        whole = cls(names=list(histories[0].names))
        for history in histories:
            for column in ("params", "values", "seconds", "start", "iteration", "failed"):
                getattr(whole, column).extend(getattr(history, column))
        return whole

    def failures_text(self) -> str:
        """The failed points and their reasons, in words ("" when none failed)."""
        return "; ".join(
            f"{dict(zip(self.names, np.round(f['params'], 4).tolist()))} failed: {f['reason']}" for f in self.failed
        )

    def to_dict(self) -> dict:
        """JSON: names, params [n, p], values [n], seconds [n], best_params [p], best_value, and
        failed [{params, reason, seconds, start, iteration}] (the points that could not be evaluated)."""
        best_params, best_value = self.best
        return {
            "names": list(self.names),
            "params": self.params,
            "values": self.values,
            "seconds": self.seconds,
            "best_params": best_params.tolist(),
            "best_value": best_value,
            "failed": self.failed,
        }


@dataclass
class OptimisationResult:
    """What an optimiser found: the best point of all its evaluations and the history of them."""

    params: list  # [P] the best point
    value: float  # the objective there
    history: OptimisationHistory  # every evaluation (of every start), labelled by start and iteration
    n_batches: int  # calls of the objective
    starts: list = field(default_factory=list)  # per start of a multi-start optimiser (calibration.lbfgsb.StartResult)


class Optimiser(Protocol):
    """calibration.lbfgsb.multistart_lbfgsb and calibration.bayesopt.bayesian_optimisation."""

    def __call__(
        self,
        objective: BatchObjective,
        bounds: Sequence[Sequence[float]],
        names: Sequence[str],
        settings: Any,
        progress: Progress | None = None,
    ) -> OptimisationResult: ...


def one_at_a_time(objective: Callable[[np.ndarray], float]) -> BatchObjective:
    """A batch objective (points [G, P] -> values [G]) of a function of one point (params [P] -> float)."""
    return lambda points: np.array([float(objective(p)) for p in points])
