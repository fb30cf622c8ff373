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


@dataclass
class OptimisationHistory:
    """Every evaluation in order: params [n, p], values [n], wall time of each (s), and for each the
    start it belongs to (0 for a single-start optimiser) and the optimiser's iteration it was made
    in (L-BFGS-B: iterations the start had completed; Bayesian optimisation: 0 for the initial
    design, then k for the k-th point chosen by expected improvement)."""

    names: list
    params: list = field(default_factory=list)
    values: list = field(default_factory=list)
    seconds: list = field(default_factory=list)
    start: list = field(default_factory=list)
    iteration: list = field(default_factory=list)

    def record(self, params: Sequence[float], value: float, seconds: float, start: int = 0, iteration: int = 0) -> None:
        """Append one evaluation: params [p], its objective value, its wall time (s)."""
        self.params.append([float(p) for p in params])
        self.values.append(float(value))
        self.seconds.append(float(seconds))
        self.start.append(int(start))
        self.iteration.append(int(iteration))

    @property
    def best(self) -> tuple[np.ndarray, float]:
        """(params [p], value) of the lowest value (the first of equal ones)."""
        k = int(np.argmin(self.values))
        return np.array(self.params[k]), self.values[k]

    @classmethod
    def concatenate(cls, histories: Sequence[OptimisationHistory]) -> OptimisationHistory:
        """One history of the evaluations of `histories` (of the same parameters), one after another."""
        whole = cls(names=list(histories[0].names))
        for history in histories:
            for column in ("params", "values", "seconds", "start", "iteration"):
                getattr(whole, column).extend(getattr(history, column))
        return whole

    def to_dict(self) -> dict:
        """JSON: names, params [n, p], values [n], seconds [n], best_params [p], best_value."""
        best_params, best_value = self.best
        return {
            "names": list(self.names),
            "params": self.params,
            "values": self.values,
            "seconds": self.seconds,
            "best_params": best_params.tolist(),
            "best_value": best_value,
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
