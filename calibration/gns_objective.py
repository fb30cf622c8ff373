"""The objective of the GNS inverse design (calibration.inverse): THE objective of design
parameters through a GNS rollout of the measured column (the checks that the column lies in the
geometry the GNS was trained on: calibration.geometry).

The design parameters (mu, e) sit in the node features of the initial graph; the trained GNS rolls
the measured column out from its first C frames; a differentiable runout turns the rollout into L*
at the measured t/t* points; THE objective (calibration.objective.runout_mse) scores it, with
gradients by automatic differentiation through the (checkpointed) rollout or without gradient.
Rollouts stop at the last measured t/t* (the frames the runout needs), a differentiated rollout runs
in checkpointed segments whose forward pass carries no autograd bookkeeping, and no point is rolled
out twice (the posterior reuses the optimum's runout). The objective counts where its online time
goes: rollouts, forward and backward seconds (GNSObjective.timing).

A rollout is chaotic in (mu, e), as the DEM is: below a few hundredths the objective is rough and
its exact gradient is large and local.

Differentiable runout: gns.runout, the twin of dem.runout's configured method (`runout`, a
dem.runout.RunoutMethod): the same discrete choice of grains, a soft top-k where dem.runout takes
a mean or a maximum, an exact running maximum for the "_reached" methods.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch

from calibration.geometry import InverseDesignError
from calibration.measured_column import MeasuredColumn
from calibration.objective import runout_mse
from dem.runout import RunoutError, RunoutMethod
from dem.trajectory import Trajectory
from gns.runout import frames_needed, soft_runout_at

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from gns.simulator import LearnedSimulator

DESIGN_NAMES = ("friction", "restitution")
# Rollout steps per checkpointed segment of a differentiated rollout (GNSObjective._rollout): the
# backward pass holds one segment's activations, ~40 MB per step per 589-grain graph at latent 64.
SEGMENT_STEPS = 10
# Graphs of one no-gradient batch (runout_values): a batch's activations outgrow the cache, so its
# cost per graph rises with its size (the calibrated quartz GNS, 4 packings of 589 grains: 19 points
# as one batch of 76 graphs cost 1.5-2.2x a graph what batches of 4-8 do); each graph's rows are
# computed apart from the others', so a point's L* is the same bits in any batch.
BATCH_GRAPHS = 8


class GNSObjective:
    """THE objective of design parameters through a GNS rollout of the measured column.

    start: a DEM trajectory of the measured column (material, a, L_i; the GNS's grain size and
    frame interval) whose first C frames start every rollout, or several (S packings of the same
    column): then every point rolls out from each, and L* is their mean curve, the quantity a DEM
    validation on S packings scores (a rollout is chaotic in its packing, as the DEM is: the mean
    over packings is smoother in theta than any one). The design parameters replace the starts'
    own; parameters the model takes but that are not designed keep the first start's values, but
    for those of `tied` ({parameter: the designed parameter whose value it takes}: an extended
    model's GNS run as the base model, whose floor friction is its grains' friction).
    Call with theta [G, P] (P = len(design_names)): G S rollouts run as one batch of graphs;
    runout_values splits its points into batches of at most batch_graphs graphs (one point at least).
    """

    def __init__(
        self,
        simulator: LearnedSimulator,
        start: Trajectory,
        measured: MeasuredColumn,
        design_names: Sequence[str] = DESIGN_NAMES,
        runout: RunoutMethod | None = None,
        temperature: float | None = None,
        checkpoint: bool = True,
        segment_steps: int = SEGMENT_STEPS,
        batch_graphs: int = BATCH_GRAPHS,
        tied: Mapping[str, str] | None = None,
    ):
        config = simulator.config
        self.simulator = simulator
        self.measured = measured
        self.runout_method = RunoutMethod.from_config(runout)
        self.design_names = list(design_names)
        self.temperature = temperature
        self.checkpoint = checkpoint
        self.segment_steps = int(segment_steps)
        self.batch_graphs = int(batch_graphs)
        unknown = [n for n in self.design_names if n not in config.parameter_names]
        if unknown:
            raise InverseDesignError(
                f"design parameter(s) {unknown} are not inputs of the GNS (it takes {config.parameter_names})"
            )
        tied = dict(tied or {})
        wrong = {k: v for k, v in tied.items() if k not in config.parameter_names or v not in self.design_names}
        if wrong:
            raise InverseDesignError(
                f"tied parameter(s) {wrong}: each must be a GNS input ({config.parameter_names}) tied to a "
                f"designed one ({self.design_names})"
            )
        starts = [start] if isinstance(start, Trajectory) else list(start)
        if not starts:
            raise InverseDesignError("GNS objective: no start trajectory to roll out from")
        for k, packing in enumerate(starts):
            where = "start trajectory" if len(starts) == 1 else f"start trajectory {k}"
            if not math.isclose(float(packing.attrs["dt_frame"]), config.dt_frame, rel_tol=1e-9):
                raise InverseDesignError(
                    f"{where}: dt_frame {packing.attrs['dt_frame']} s differs from the "
                    f"GNS's {config.dt_frame} s (one GNS step is one frame)"
                )
            if packing.n_frames < config.n_input_frames:
                raise InverseDesignError(
                    f"{where} has {packing.n_frames} frames; the GNS needs C = {config.n_input_frames} to start from"
                )
            for key in ("L_i", "t_star"):
                if not math.isclose(float(packing.attrs[key]), float(starts[0].attrs[key]), rel_tol=1e-9):
                    raise InverseDesignError(
                        f"{where}: {key} {packing.attrs[key]} differs from the first start's "
                        f"{starts[0].attrs[key]} (the packings must be of one column)"
                    )
        start = starts[0]
        self.n_packings = len(starts)
        self.t_star = float(start.attrs["t_star"])
        self.L_i = float(start.attrs["L_i"])
        self.dt_frame = config.dt_frame
        self.n_frames = frames_needed(measured.t_over_tstar, self.t_star, self.dt_frame)  # frames the runout reads
        self.n_steps = max(self.n_frames - config.n_input_frames, 0)
        dtype = simulator.bounds.dtype
        device = simulator.bounds.device
        # the S packings side by side, as one graph each: first C frames [C, sum N_s, 2]
        self.initial = torch.cat(
            [torch.as_tensor(p.positions[: config.n_input_frames], dtype=dtype, device=device) for p in starts], dim=1
        )
        self.radius = torch.cat([torch.as_tensor(p.radius, dtype=dtype, device=device) for p in starts])
        self.particle_type = torch.cat(
            [torch.as_tensor(p.particle_type, dtype=torch.long, device=device) for p in starts]
        )
        self.packing_sizes = [p.n_particles for p in starts]  # N_s
        self.fixed = torch.tensor([float(start.attrs[n]) for n in config.parameter_names], dtype=dtype, device=device)
        self.layout = torch.tensor(
            [[float(p.attrs["L_i"]), float(p.attrs["H_i"])] for p in starts], dtype=dtype, device=device
        )
        self.design_index = [config.parameter_names.index(n) for n in self.design_names]
        self.tied_index = [config.parameter_names.index(n) for n in tied if n not in self.design_names]
        self.tied_source = [config.parameter_names.index(tied[n]) for n in tied if n not in self.design_names]
        self.target = torch.as_tensor(measured.runout, dtype=dtype, device=device)
        self.n_particles = sum(self.packing_sizes)  # grains of one point's rollouts (all packings)
        # where the online time goes: rollouts (graphs rolled out), forward and backward seconds
        self.timing = {"rollouts": 0, "forward_s": 0.0, "backward_s": 0.0}
        self._runouts: dict[tuple, np.ndarray] = {}  # L* [K] of every point rolled out, by its bytes

    def _context(self, theta: torch.Tensor):
        """The batch of G S graphs for theta [G, P]: point g's packing s is graph g S + s."""
        from gns.simulator import Context

        g, s = theta.shape[0], self.n_packings
        parameters = self.fixed.repeat(g * s, 1)
        index = torch.tensor(self.design_index, device=theta.device)
        parameters = parameters.index_copy(1, index, theta.repeat_interleave(s, dim=0))
        if self.tied_index:
            tied = torch.tensor(self.tied_index, device=theta.device)
            parameters = parameters.index_copy(1, tied, parameters[:, self.tied_source])
        sizes = torch.tensor(self.packing_sizes, device=theta.device).repeat(g)
        return Context(
            self.particle_type.repeat(g),
            self.radius.repeat(g),
            parameters,
            self.layout.repeat(g, 1),
            torch.arange(g * s, device=theta.device).repeat_interleave(sizes),
        )

    def runout(self, theta: torch.Tensor) -> torch.Tensor:
        """L* [G, K] at the measured t/t* for theta [G, P] (differentiable when theta requires grad):
        the mean over the start packings of each one's L*."""
        from gns.rollout import RolloutError

        g = theta.shape[0]
        t0 = time.perf_counter()
        try:
            positions = self._rollout(theta)
        except (RolloutError, ValueError) as exc:
            raise InverseDesignError(f"GNS rollout at {self._describe(theta)} failed: {exc}") from None
        positions = positions.reshape(positions.shape[0], g, self.n_particles, 2)
        bounds = np.cumsum([0] + self.packing_sizes)
        radii = [self.radius[bounds[s] : bounds[s + 1]] for s in range(self.n_packings)]
        try:  # a rollout spread too thin has no front by the configured rule
            runout = torch.stack(
                [
                    torch.stack(
                        [
                            soft_runout_at(
                                positions[:, j, bounds[s] : bounds[s + 1]],
                                radii[s],
                                self.L_i,
                                self.t_star,
                                self.dt_frame,
                                self.measured.t_over_tstar,
                                self.runout_method,
                                self.temperature,
                            )
                            for s in range(self.n_packings)
                        ]
                    ).mean(dim=0)
                    for j in range(g)
                ]
            )
        except RunoutError as exc:
            raise InverseDesignError(f"GNS rollout at {self._describe(theta)} has no runout: {exc}") from None
        self.timing["rollouts"] += g * self.n_packings
        self.timing["forward_s"] += time.perf_counter() - t0
        return runout

    def _segment(self, window: torch.Tensor, theta: torch.Tensor, n_steps: int) -> torch.Tensor:
        """The n_steps frames [n_steps, G N, 2] after the C frames `window` [C, G N, 2]."""
        from gns.rollout import rollout

        result = rollout(self.simulator, window, self._context(theta), n_steps, checkpoint=False)
        return result.positions[window.shape[0] :]

    def _rollout(self, theta: torch.Tensor) -> torch.Tensor:
        """Positions [C + n_steps, G N, 2] for theta [G, P].

        With a gradient to take, the rollout runs in segments of segment_steps steps, each under a
        (reentrant) checkpoint: the forward pass runs without autograd bookkeeping (as fast as a
        no-grad rollout) and keeps only each segment's first C frames; backward recomputes one
        segment at a time with autograd. Memory: one segment's activations (~40 MB per step per
        589-grain graph) instead of the whole rollout's. The gradient is the same as without
        checkpoints (tests/test_inverse.py)."""
        initial = self.initial.repeat(1, theta.shape[0], 1)  # [C, G sum N_s, 2]
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
        theta = torch.as_tensor(
            np.atleast_2d(np.asarray(points, np.float64)),
            dtype=self.simulator.bounds.dtype,
            device=self.simulator.bounds.device,
        )
        return theta.clone().requires_grad_(requires_grad)

    def _checked(self, values: np.ndarray, points) -> np.ndarray:
        if not np.all(np.isfinite(values)):
            bad = np.atleast_2d(points)[~np.isfinite(values)]
            raise InverseDesignError(f"GNS objective is not finite at {self._describe(bad)}: no optimum from it")
        return values

    def _key(self, point) -> bytes:
        """A point as the model sees it (its dtype), so a cached runout is the one a rollout would give."""
        return self._theta(point).cpu().numpy().tobytes()

    def evaluated(self) -> tuple[np.ndarray, np.ndarray]:
        """(points [n, P], L* [n, K]) of every point rolled out so far, the points as the model saw
        them (its dtype): what the inverse design has learnt of the GNS's response."""
        dtype = torch.empty(0, dtype=self.simulator.bounds.dtype).numpy().dtype
        points = [np.frombuffer(key, dtype=dtype).astype(float) for key in self._runouts]
        width = len(self.design_names)
        return np.reshape(points, (-1, width)), np.reshape(list(self._runouts.values()), (len(points), -1))

    def runout_values(self, points: ArrayLike, allow_failed: bool = False) -> np.ndarray:
        """L* [G, K] (numpy, no gradient) at points [G, P], in batches of at most batch_graphs graphs;
        points rolled out before are not rolled out again (a rollout is deterministic). allow_failed:
        a NaN row (logged with the reason) at a point whose rollout fails, instead of an
        InverseDesignError."""
        points = np.atleast_2d(np.asarray(points, np.float64))
        if allow_failed:
            return self._or_nan(points, lambda p: (self.runout_values(p),), [(len(self.measured.runout),)])[0]
        missing = [j for j, p in enumerate(points) if self._key(p) not in self._runouts]
        per_batch = max(1, self.batch_graphs // self.n_packings)
        for first in range(0, len(missing), per_batch):
            batch = missing[first : first + per_batch]
            with torch.no_grad():
                fresh = self.runout(self._theta(points[batch])).double().cpu().numpy()
            self._runouts.update((self._key(points[j]), r) for j, r in zip(batch, fresh))
        return np.array([self._runouts[self._key(p)] for p in points])

    def _or_nan(self, points: np.ndarray, evaluate, shapes: Sequence[tuple[int, ...]]) -> tuple:
        """evaluate(points [G, P]) -> a tuple of arrays [G, *shape] for each of `shapes` (one point's
        shape of each output), with NaN for every point that fails (its rollout raised, or its
        objective is not finite): a batch that fails is evaluated point by point, so one diverged
        rollout does not take its batch with it."""
        try:
            return evaluate(points)
        except InverseDesignError as exc:
            if len(points) > 1:
                parts = [self._or_nan(point[None], evaluate, shapes) for point in points]
                return tuple(np.concatenate(column) for column in zip(*parts))
            log.warning("%s (a failed point: NaN)", exc)
            return tuple(np.full((1, *shape), np.nan) for shape in shapes)

    def values(self, points: ArrayLike, allow_failed: bool = False) -> np.ndarray:
        """Objective [G] at points [G, P], no gradient. allow_failed: NaN (logged with the reason) at a
        point whose rollout fails or whose objective is not finite, instead of an InverseDesignError
        (the optimiser records it as a failed point and goes on)."""
        if allow_failed:
            return self._or_nan(np.atleast_2d(points), lambda p: (self.values(p),), [()])[0]
        runout = self.runout_values(points)
        return self._checked(np.array([runout_mse(r, self.measured.runout) for r in runout]), points)

    def values_and_gradients(self, points: ArrayLike, allow_failed: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(objective [G], d objective / d theta [G, P]) by backpropagation through the rollout;
        allow_failed: NaN value and gradient at a point that fails (as `values`)."""
        if allow_failed:
            return self._or_nan(np.atleast_2d(points), self.values_and_gradients, [(), (len(self.design_names),)])
        theta = self._theta(points, requires_grad=True)
        with torch.enable_grad():
            runout = self.runout(theta)
            values = torch.stack([runout_mse(r, self.target) for r in runout])
            self._runouts.update(
                (self._key(p), r) for p, r in zip(np.atleast_2d(points), runout.detach().double().cpu().numpy())
            )
            t0 = time.perf_counter()
            values.sum().backward()  # graphs are independent: row g of the gradient is d value_g
            self.timing["backward_s"] += time.perf_counter() - t0
        values = self._checked(values.detach().double().cpu().numpy(), points)
        gradients = theta.grad.double().cpu().numpy()
        if not np.all(np.isfinite(gradients)):
            raise InverseDesignError(f"GNS gradient is not finite at {self._describe(points)}")
        return values, gradients
