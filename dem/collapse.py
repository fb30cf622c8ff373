"""The builtin engine's collapse run: settle behind the gate, remove it at t = 0, record frames.

A long run checkpoints: every `checkpoint_every_s` of wall time it writes its state and the frames
so far (atomically) to a checkpoint file; run again with the same file, it resumes from there and
gives the same bits as a run never stopped. A checkpoint of another case, packing, engine version
or thread count, or one that does not read whole, is set aside with a warning and the run starts
clean. The file is removed once the run is done.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from dem.atomic import StrPath, atomic_path
from dem.case import CollapseCase
from dem.forces import ContactLaw
from dem.integrate import ENGINE_VERSION, State, record
from dem.packing import blowup_box, check_grain_count, settle_column, walls_open
from dem.trajectory import GRAIN, Trajectory, engine_attrs

log = logging.getLogger(__name__)

CHECKPOINT_EVERY_S = 60.0  # wall seconds between checkpoints of a long run
STATE_ARRAYS = ("x", "v", "spin", "radius", "mass", "wall_history", "x_built")
STATE_SCALARS = ("skin", "time", "steps", "rebuilds")


def state_from_packing(case: CollapseCase, packing: Trajectory) -> State:
    """Grains at rest at the last frame of `packing` (a settled-column trajectory): positions (m),
    radii (m), masses from case.density (kg/m^3)."""
    check_grain_count(case, packing)
    return State.at_rest(packing.positions[-1], packing.radius, case.density)


def run_fingerprint(case: CollapseCase, packing: Trajectory, threads: int) -> str:
    """What a checkpoint must match to be resumed: the case (but its name), the packing, the engine
    version and the thread count (the bits depend on each)."""
    physics = {key: value for key, value in case.to_dict().items() if key != "name"}
    digest = hashlib.sha256(json.dumps(physics, sort_keys=True, default=str).encode())
    digest.update(np.ascontiguousarray(packing.positions[-1], np.float64).tobytes())
    digest.update(np.ascontiguousarray(packing.radius, np.float64).tobytes())
    digest.update(f"{ENGINE_VERSION} threads={threads}".encode())
    return digest.hexdigest()


def write_checkpoint(path: StrPath, fingerprint: str, state: State, frames: np.ndarray, wall_s: float) -> None:
    """The run's state, its frames so far [T, N, 2] and its wall seconds so far, atomically."""
    start, partner, history = state.pairs
    arrays = {name: getattr(state, name) for name in STATE_ARRAYS}
    arrays.update({name: np.asarray(getattr(state, name)) for name in STATE_SCALARS})
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.savez(
            handle,
            fingerprint=np.asarray(fingerprint),
            frames=frames,
            wall_s=np.asarray(wall_s),
            pair_start=start,
            pair_partner=partner,
            pair_history=history,
            **arrays,
        )


def read_checkpoint(path: StrPath, fingerprint: str, n_frames: int) -> tuple[State, np.ndarray, float] | None:
    """(state, frames, wall seconds so far) of the checkpoint at `path` when it exists, reads whole
    and matches `fingerprint`; else None, with a warning naming the file and why it was set aside."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        with np.load(path) as data:
            if str(data["fingerprint"]) != fingerprint:
                raise ValueError("it is of another case, packing, engine version or thread count")
            frames = data["frames"]
            state = State(
                **{name: data[name].copy() for name in STATE_ARRAYS},
                skin=float(data["skin"]),
                time=float(data["time"]),
                steps=int(data["steps"]),
                rebuilds=int(data["rebuilds"]),
                pairs=(data["pair_start"].copy(), data["pair_partner"].copy(), data["pair_history"].copy()),
            )
            wall_s = float(data["wall_s"])
        if frames.shape[0] != n_frames or frames.shape[1:] != state.x.shape:
            raise ValueError(f"frames of shape {frames.shape} do not fit the case")
    except Exception as exc:  # a truncated or foreign file: never resume from it
        log.warning("checkpoint %s set aside, starting clean: %s: %s", path, type(exc).__name__, exc)
        return None
    return state, frames, wall_s


def simulate_collapse(
    case: CollapseCase,
    packing: Trajectory | None = None,
    progress: Callable[[float], None] | None = None,
    threads: int = 1,
    checkpoint: StrPath | None = None,
    checkpoint_every_s: float = CHECKPOINT_EVERY_S,
) -> Trajectory:
    """Collapse trajectory: case.n_frames frames every case.frame_interval, gate removed at t = 0.

    packing: the settled column (dem.packing.settle_column); settled here when None.
    progress: callable(fraction_done) or None.
    threads: as in dem.integrate.run (recorded: the trajectory's bits depend on it).
    checkpoint: a file to checkpoint to every checkpoint_every_s wall seconds and to resume from
    (see the module's docstring); None: no checkpoints. Attribute resumed_from_frame: the frame the
    run resumed from (0: from the start).
    """
    if packing is None:
        packing = settle_column(case, threads=threads)
    fingerprint = run_fingerprint(case, packing, threads)
    resumed = read_checkpoint(checkpoint, fingerprint, case.n_frames) if checkpoint is not None else None
    if resumed is None:
        state, frames, wall_before = state_from_packing(case, packing), None, 0.0
    else:
        state, frames, wall_before = resumed
    first_frame = round(state.time / case.frame_interval)
    started = last_save = time.perf_counter()

    def save(k: int, frames: np.ndarray) -> None:
        nonlocal last_save
        if checkpoint is not None and k < case.n_frames - 1 and time.perf_counter() - last_save >= checkpoint_every_s:
            write_checkpoint(checkpoint, fingerprint, state, frames, wall_before + time.perf_counter() - started)
            last_save = time.perf_counter()

    frames, stats = record(
        state,
        ContactLaw.from_case(case),
        walls_open(case),
        blowup_box(case),
        case.time_step,
        case.frame_interval,
        case.n_frames,
        label=f"case {case.name or '?'}",
        progress=progress,
        threads=threads,
        frames=frames,
        after_frame=save,
    )
    if checkpoint is not None and os.path.exists(checkpoint):
        os.unlink(checkpoint)
    wall_s = wall_before + stats.wall_time
    attrs = engine_attrs(case, "builtin", ENGINE_VERSION)
    attrs.update(
        dt=stats.extra["dt"],
        steps=state.steps,
        wall_time_s=wall_s,
        particle_steps_per_second=state.steps * case.n_particles / max(wall_s, 1e-12),
        threads=threads,
        settled_height=packing.attrs.get("settled_height", np.nan),
        resumed_from_frame=first_frame,
    )
    if not np.all(np.isfinite(frames)):  # a checkpoint's frames not all recorded: never written out
        raise RuntimeError(f"case {case.name or '?'}: frames missing after the run (checkpoint {checkpoint})")
    return Trajectory(
        positions=frames,
        radius=packing.radius.copy(),
        particle_type=np.full(packing.n_particles, GRAIN, np.int32),
        attrs=attrs,
    )
