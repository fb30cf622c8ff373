"""Rollout: from the first C frames, K learned steps; differentiable, with gradient checkpointing.

`rollout` is the differentiable core (tensors in, tensors out): gradients flow to the DEM
parameters, the initial layout and the initial positions. With `checkpoint=True` each step runs
under torch.utils.checkpoint, so backward keeps only each step's input positions [N, C, 2]
(O(K N) numbers) instead of every step's graph activations (O(K E latent M)), and recomputes a
step's activations when its gradient is needed: memory no longer grows with the graph network's
size times K.

`rollout_trajectory` runs a DEM trajectory's case forward and returns a `Trajectory` (engine
"gns") that dem.runout and dem.plots read like any DEM output.

A rollout whose positions turn non-finite or leave the box (by more than one mean grain
diameter, as the builtin engine's blow-up check) raises RolloutError, or with on_invalid="flag"
stops there and says so in the result.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint as checkpointed

from dem.trajectory import Trajectory
from gns.simulator import Context, LearnedSimulator

# attributes of a DEM run that describe that run, not the case; not carried into a rollout
RUN_ATTRS = ("steps", "wall_time_s", "particle_steps_per_second", "dt")


class RolloutError(RuntimeError):
    """The rollout turned non-finite or left the box; the message names the step."""


@dataclass
class Rollout:
    positions: torch.Tensor  # [C + steps_done, N, 2] (m)
    valid: bool
    problem: str | None  # why it stopped early, None when valid


def check_parameters(simulator: LearnedSimulator, parameters: torch.Tensor, layout: torch.Tensor) -> None:
    """ValueError when a parameter or L_i/H_i lies outside the range the model was trained on.

    parameters [G, P] or [P] (physical units, config.parameter_names order); layout [G, 2] or [2]
    (L_i, H_i in m)."""
    c = simulator.config
    names = c.parameter_names + ["L_i", "H_i"]
    values = (
        torch.cat([parameters.detach().reshape(-1, len(c.parameter_names)), layout.detach().reshape(-1, 2)], dim=1)
        .cpu()
        .double()
    )
    for k, name in enumerate(names):
        low, high = c.parameter_ranges[name]
        tolerance = 1e-6 * max(abs(low), abs(high), 1e-12)
        bad = (values[:, k] < low - tolerance) | (values[:, k] > high + tolerance)
        if bool(bad.any()):
            raise ValueError(
                f"{name} = {values[bad, k][0].item():.6g} lies outside the range [{low}, {high}] "
                "the model was trained on"
            )


def rollout(
    simulator: LearnedSimulator,
    initial_positions: torch.Tensor,
    context: Context,
    n_steps: int,
    checkpoint: bool = True,
    on_invalid: str = "raise",
) -> Rollout:
    """initial_positions [C, N, 2] (m) -> Rollout with positions [C + n_steps, N, 2].

    Gradients reach initial_positions, context.parameters and context.layout when they require
    grad. checkpoint: recompute each step in backward instead of storing it (same gradient).
    """
    if on_invalid not in ("raise", "flag"):
        raise ValueError(f"on_invalid must be 'raise' or 'flag', got {on_invalid!r}")
    c = simulator.config
    if initial_positions.shape[0] != c.n_input_frames:
        raise ValueError(
            f"initial_positions has {initial_positions.shape[0]} frames, the model needs C = {c.n_input_frames}"
        )
    check_parameters(simulator, context.parameters, context.layout)
    margin = 2.0 * c.mean_radius
    low = simulator.bounds[:, 0] - margin
    high = simulator.bounds[:, 1] + margin
    sequence = initial_positions.transpose(0, 1)  # [N, C, 2]
    frames = list(initial_positions)

    def step(sequence, parameters, layout, radius):
        ctx = Context(context.particle_type, radius, parameters, layout, context.graph_index)
        return simulator.predict_positions(sequence, ctx)

    use_checkpoint = checkpoint and torch.is_grad_enabled()
    for k in range(n_steps):
        args = (sequence, context.parameters, context.layout, context.radius)
        position = checkpointed(step, *args, use_reentrant=False) if use_checkpoint else step(*args)
        problem = _problem(position.detach(), low, high)
        if problem:
            message = f"rollout step {k + 1} of {n_steps} (frame {c.n_input_frames + k}): {problem}"
            if on_invalid == "raise":
                raise RolloutError(message)
            return Rollout(torch.stack(frames), False, message)
        frames.append(position)
        sequence = torch.cat([sequence[:, 1:], position[:, None]], dim=1)
    return Rollout(torch.stack(frames), True, None)


def _problem(position, low, high) -> str | None:
    finite = torch.isfinite(position).all(dim=1)
    if not bool(finite.all()):
        return f"{int((~finite).sum())} particle(s) have non-finite positions"
    outside = ((position < low) | (position > high)).any(dim=1)
    if bool(outside.any()):
        return (
            f"{int(outside.sum())} particle(s) left the box {low.tolist()}..{high.tolist()} m "
            f"(e.g. at {position[outside][0].tolist()})"
        )
    return None


def context_from_trajectory(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    parameters: dict | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Context:
    """The rollout context of a trajectory's case; `parameters` overrides DEM parameters by name."""
    names = simulator.config.parameter_names
    values = {name: float(trajectory.attrs[name]) for name in names}
    values.update(parameters or {})
    unknown = set(parameters or {}) - set(names)
    if unknown:
        raise ValueError(f"parameters {sorted(unknown)} are not inputs of this model (it takes {names})")
    return Context.single(
        torch.as_tensor(trajectory.particle_type, dtype=torch.long, device=device),
        torch.as_tensor(trajectory.radius, dtype=dtype, device=device),
        torch.tensor([values[n] for n in names], dtype=dtype, device=device),
        torch.tensor([float(trajectory.attrs["L_i"]), float(trajectory.attrs["H_i"])], dtype=dtype, device=device),
    )


def rollout_trajectory(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    n_steps: int | None = None,
    parameters: dict | None = None,
    on_invalid: str = "flag",
    model_name: str = "",
) -> Trajectory:
    """GNS rollout of `trajectory`'s case from its first C frames (no gradient), as a Trajectory.

    n_steps: default runs to the trajectory's last frame. parameters: override DEM parameters by
    name (e.g. {"friction": 0.4}). The result's attrs are the case's, with engine "gns",
    rollout_valid (0/1) and rollout_problem; wall_time_s is the rollout's own time.
    """
    c = simulator.config
    if abs(float(trajectory.attrs["dt_frame"]) - c.dt_frame) > 1e-9 * c.dt_frame:
        raise ValueError(
            f"trajectory dt_frame {trajectory.attrs['dt_frame']} s differs from the model's "
            f"{c.dt_frame} s (one GNS step is one frame)"
        )
    needed = c.n_input_frames + (1 if n_steps is None else 0)  # run to its last frame: one to predict
    if trajectory.n_frames < needed:
        raise ValueError(
            f"{trajectory.source or 'trajectory'}: {trajectory.n_frames} frames, too few for a GNS rollout "
            f"from C = {c.n_input_frames} input frames (needs {needed})"
        )
    n_steps = trajectory.n_frames - c.n_input_frames if n_steps is None else n_steps
    device = simulator.bounds.device
    context = context_from_trajectory(simulator, trajectory, parameters, device)
    initial = torch.as_tensor(trajectory.positions[: c.n_input_frames], dtype=torch.float32, device=device)
    start = time.perf_counter()
    with torch.no_grad():
        result = rollout(simulator, initial, context, n_steps, checkpoint=False, on_invalid=on_invalid)
    elapsed = time.perf_counter() - start
    attrs = {k: v for k, v in trajectory.attrs.items() if k not in RUN_ATTRS}
    for name, value in (parameters or {}).items():
        for wall_key in (f"{name}_wall",):  # a wall value that followed the grain value keeps following it
            if wall_key in attrs and attrs[wall_key] == trajectory.attrs[name] and wall_key not in c.parameter_names:
                attrs[wall_key] = float(value)
        attrs[name] = float(value)
    attrs.update(
        engine="gns",
        engine_version=model_name or "gns",
        wall_time_s=elapsed,
        rollout_valid=int(result.valid),
        rollout_problem=result.problem or "",
        rollout_steps=int(result.positions.shape[0] - c.n_input_frames),
    )
    return Trajectory(
        positions=result.positions.cpu().numpy().astype(np.float32),
        radius=np.asarray(trajectory.radius),
        particle_type=np.asarray(trajectory.particle_type),
        attrs=attrs,
    )
