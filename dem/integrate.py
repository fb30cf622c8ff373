"""The builtin engine's time stepping: forces from the contact law (dem.forces), symplectic Euler steps.

State is plain arrays (positions, velocities, spins, pair list with contact history). One call of
`advance` runs many small steps in compiled code and returns a status, so the Python driver only
runs between output frames: it records frames, checks for blow-up and reports progress.

Grains move in 2D but carry sphere mass m = rho pi d^3 / 6 and inertia 2/5 m r^2, as in MFIX 2D
DEM (spheres in a one-diameter-deep domain). LIGGGHTS `enforce2d` would give disc inertia, so the
LIGGGHTS engine runs one layer of spheres instead (dem/engines/liggghts.py).
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from dem.case import GRAVITY, sphere_mass
from dem.contact import FAST_MATH
from dem.forces import N_WALLS, ContactLaw, _forces, _range_forces, _sidewall_drag
from dem.kernel_sources import KERNEL_MODULES, digest, kernel
from dem.neighbours import build_pairs, build_pairs_threaded, default_skin, empty_pairs

log = logging.getLogger(__name__)

# recorded in every trajectory the engine writes. 2: settles at contact_time / 20; 3: two or more
# threads split the grains by contact work (one thread's bits unchanged); 4: the settle's step
# follows the collapse's (2.5x; the default's bits unchanged); 5: IEEE arithmetic (no fastmath), the
# same bits on every x86-64 processor. After the "+": the first 12 hex digits of the digest of the
# kernels' code (dem.kernel_sources), so that a trajectory names the code that made it and a
# checkpoint of other code is not resumed
ENGINE_VERSION = f"builtin-5+{digest(*KERNEL_MODULES)[:12]}"

# status codes from `advance`
OK, NON_FINITE, OVERLAP, LEFT_BOX = 0, 1, 2, 3
MAX_OVERLAP_RATIO = 0.25  # overlap / smaller diameter beyond which the run has blown up


class SimulationError(RuntimeError):
    """The run blew up; the message names the case and the step."""


@dataclass
class State:
    """Grains: x [N, 2] (m), v [N, 2] (m/s), spin [N] (rad/s), radius [N] (m), mass [N] (kg).

    Contact history: pairs = (start, partner, history [M, 2]) and wall_history [N, N_WALLS, 2],
    column 0 the tangential spring (m), column 1 the rolling torque (N m).
    time (s) counts from the gate's release.
    """

    x: np.ndarray
    v: np.ndarray
    spin: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    skin: float = 0.0
    pairs: tuple = field(default_factory=empty_pairs)
    wall_history: np.ndarray | None = None
    x_built: np.ndarray | None = None
    time: float = 0.0
    steps: int = 0
    rebuilds: int = 0

    @classmethod
    def at_rest(cls, positions: np.ndarray, radius: np.ndarray, density: float) -> State:
        """Grains at `positions` [N, 2] (m) with `radius` [N] (m) and material `density` (kg/m^3), at rest."""
        positions = np.ascontiguousarray(positions, np.float64)
        radius = np.ascontiguousarray(radius, np.float64)
        n = len(radius)
        return cls(
            x=positions.copy(),
            v=np.zeros((n, 2)),
            spin=np.zeros(n),
            radius=radius,
            mass=sphere_mass(density, 2 * radius),
            skin=default_skin(radius),
            wall_history=np.zeros((n, N_WALLS, 2)),
        )

    @property
    def inertia(self) -> np.ndarray:
        return 0.4 * self.mass * self.radius**2

    def kinetic_energy(self) -> float:
        return float(0.5 * np.sum(self.mass[:, None] * self.v**2) + 0.5 * np.sum(self.inertia * self.spin**2))


@kernel(fastmath=FAST_MATH)
def _move(i_start, i_end, x, v, spin, force, torque, inv_mass, inv_inertia, x_built, half_skin2, dt):
    """One symplectic Euler step (kick, then drift) of grains i_start <= i < i_end under force
    [N, 2] (N) and torque [N] (N m). True when one of them moved more than half the skin since the
    pair list was built (half_skin2 = (skin / 2)^2), or is not finite: the list needs a rebuild."""
    moved = False
    for i in range(i_start, i_end):
        v[i, 0] += force[i, 0] * inv_mass[i] * dt
        v[i, 1] += force[i, 1] * inv_mass[i] * dt
        spin[i] += torque[i] * inv_inertia[i] * dt
        x[i, 0] += v[i, 0] * dt
        x[i, 1] += v[i, 1] * dt
        ddx = x[i, 0] - x_built[i, 0]
        ddy = x[i, 1] - x_built[i, 1]
        if not ddx * ddx + ddy * ddy < half_skin2:  # also true for NaN
            moved = True
    return moved


@kernel()
def _escaped(x, box):
    """Status of positions x [N, 2] (m) before a pair-list build: 1 (NON_FINITE) for a grain not
    finite, 3 (LEFT_BOX) for one outside box = (x_min, x_max, y_min, y_max) (m), else 0 (OK)."""
    for i in range(x.shape[0]):
        if not (math.isfinite(x[i, 0]) and math.isfinite(x[i, 1])):
            return 1
        if x[i, 0] < box[0] or x[i, 0] > box[1] or x[i, 1] < box[2] or x[i, 1] > box[3]:
            return 3
    return 0


@kernel(fastmath=FAST_MATH)
def _advance(
    x,
    v,
    spin,
    radius,
    mass,
    x_built,
    skin,
    start,
    partner,
    history,
    wall_history,
    law,
    walls,
    box,
    time,
    dt,
    n_steps,
    gravity,
):
    """Run up to n_steps symplectic Euler steps (kick, then drift) from `time` (s).

    Returns (status, steps_done, start, partner, history, rebuilds, worst_overlap_ratio); the pair
    list is returned because a rebuild replaces it.
    """
    n = x.shape[0]
    force = np.empty((n, 2))
    torque = np.empty(n)
    load = np.empty(n)
    inv_mass = 1.0 / mass
    inv_inertia = 1.0 / (0.4 * mass * radius * radius)
    rebuilds = 0
    worst_all = 0.0
    half_skin2 = 0.25 * skin * skin
    for step in range(n_steps):
        worst = _forces(
            x,
            v,
            spin,
            radius,
            mass,
            start,
            partner,
            history,
            wall_history,
            law,
            walls,
            time + step * dt,
            dt,
            gravity,
            force,
            torque,
            load,
        )
        worst_all = max(worst_all, worst)
        if worst > MAX_OVERLAP_RATIO:
            return 2, step, start, partner, history, rebuilds, worst_all
        if _move(0, n, x, v, spin, force, torque, inv_mass, inv_inertia, x_built, half_skin2, dt):
            status = _escaped(x, box)
            if status != 0:
                return status, step + 1, start, partner, history, rebuilds, worst_all
            start, partner, history = build_pairs(x, radius, skin, start, partner, history)
            x_built[:, :] = x
            rebuilds += 1
    return 0, n_steps, start, partner, history, rebuilds, worst_all


# The work of a grain for the threads' split, in listed pairs: a pair in contact costs about 4 times
# one only listed (its contact law against a distance check), the walls about 2. Measured on the
# full-scale column at 0.25 and 2 t* (2 threads, weights 0-25 tried): 4 runs 1.1x and 1.4x faster
# than weighting the listed pairs alone, where the deposit's touching grains overload one thread.
CONTACT_WORK = 4.0
WALL_WORK = 2.0


@kernel()
def _chunk_bounds(x, radius, start, partner, n_chunks):
    """Chunks of grains for the threads: bounds [n_chunks + 1] split 0..N into ranges of about
    equal work (a grain's listed pairs, CONTACT_WORK for each of them in contact at x [N, 2] (m)
    with radius [N] (m), WALL_WORK for its walls), and reach [n_chunks], one past the last grain a
    chunk's pairs touch (start [N+1], partner [M]: the CSR pair list). Chunk c adds forces to grains
    bounds[c] <= i < reach[c] only."""
    n = start.shape[0] - 1
    work = np.empty(n + 1)
    work[0] = 0.0
    for i in range(n):
        cost = WALL_WORK + (start[i + 1] - start[i])
        for k in range(start[i], start[i + 1]):
            j = partner[k]
            dx, dy, reach = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], radius[i] + radius[j]
            if dx * dx + dy * dy < reach * reach:
                cost += CONTACT_WORK
        work[i + 1] = work[i] + cost
    bounds = np.empty(n_chunks + 1, np.int64)
    bounds[0], bounds[n_chunks] = 0, n
    i = 0
    for c in range(1, n_chunks):
        while i < n and work[i] < c * work[n] / n_chunks:
            i += 1
        bounds[c] = i
    reach = np.empty(n_chunks, np.int64)
    for c in range(n_chunks):
        reach[c] = bounds[c + 1]
        for k in range(start[bounds[c]], start[bounds[c + 1]]):
            reach[c] = max(reach[c], partner[k] + 1)
    return bounds, reach


@kernel(parallel=True, fastmath=FAST_MATH)
def _advance_threaded(
    x,
    v,
    spin,
    radius,
    mass,
    x_built,
    skin,
    start,
    partner,
    history,
    wall_history,
    law,
    walls,
    box,
    time,
    dt,
    n_steps,
    gravity,
    n_chunks,
):
    """`_advance` on n_chunks threads: the same steps, the same returns.

    The grains are split into n_chunks ranges of about equal work, one per thread. A range adds
    the forces of its pairs and walls to its own grains, and a pair's reaction on a grain of a
    later range to its own spill buffer; then each grain adds the earlier ranges' spills in range
    order, then its side-wall drag (which needs its whole contact load), and moves. Grains are
    numbered row by row (dem.packing.pour_column), so a range's pairs reach little beyond it and
    the spills are short. Which thread runs which range does not matter: the bits depend on
    n_chunks only (another count: other bits, the same physics).
    """
    n = x.shape[0]
    force = np.empty((n, 2))
    torque = np.empty(n)
    load = np.empty(n)
    spill_force = np.zeros((n_chunks, n, 2))
    spill_torque = np.zeros((n_chunks, n))
    spill_load = np.zeros((n_chunks, n))
    worst_chunk = np.zeros(n_chunks)
    moved_chunk = np.zeros(n_chunks, np.bool_)
    inv_mass = 1.0 / mass
    inv_inertia = 1.0 / (0.4 * mass * radius * radius)
    half_skin2 = 0.25 * skin * skin
    bounds, reach = _chunk_bounds(x, radius, start, partner, n_chunks)
    rebuilds = 0
    worst_all = 0.0
    for step in range(n_steps):
        for c in nb.prange(n_chunks):
            worst_chunk[c] = _range_forces(
                bounds[c],
                bounds[c + 1],
                reach[c],
                x,
                v,
                spin,
                radius,
                mass,
                start,
                partner,
                history,
                wall_history,
                law,
                walls,
                time + step * dt,
                dt,
                gravity,
                force,
                torque,
                load,
                spill_force[c],
                spill_torque[c],
                spill_load[c],
            )
        worst = 0.0
        for c in range(n_chunks):
            worst = max(worst, worst_chunk[c])
        worst_all = max(worst_all, worst)
        if worst > MAX_OVERLAP_RATIO:
            return 2, step, start, partner, history, rebuilds, worst_all
        for c in nb.prange(n_chunks):
            for b in range(c):  # earlier ranges whose pairs reach into this one
                for i in range(bounds[c], min(reach[b], bounds[c + 1])):
                    force[i, 0] += spill_force[b, i, 0]
                    force[i, 1] += spill_force[b, i, 1]
                    torque[i] += spill_torque[b, i]
                    load[i] += spill_load[b, i]
            _sidewall_drag(bounds[c], bounds[c + 1], v, radius, load, law, gravity, force)
            moved_chunk[c] = _move(
                bounds[c], bounds[c + 1], x, v, spin, force, torque, inv_mass, inv_inertia, x_built, half_skin2, dt
            )
        rebuild = False
        for c in range(n_chunks):
            rebuild = rebuild or moved_chunk[c]
        if rebuild:
            status = _escaped(x, box)
            if status != 0:
                return status, step + 1, start, partner, history, rebuilds, worst_all
            start, partner, history = build_pairs_threaded(x, radius, skin, start, partner, history, bounds)
            x_built[:, :] = x
            bounds, reach = _chunk_bounds(x, radius, start, partner, n_chunks)
            rebuilds += 1
    return 0, n_steps, start, partner, history, rebuilds, worst_all


STATUS_TEXT = {
    NON_FINITE: "non-finite position",
    OVERLAP: f"overlap beyond {MAX_OVERLAP_RATIO} of a diameter",
    LEFT_BOX: "a grain left the box",
}


def usable_threads(requested: int) -> int:
    """Threads one run may use: `requested` (config dem.threads), capped at the cores this process
    may run on, with a warning naming both when it asked for more."""
    requested = int(requested)
    if requested < 1:
        raise ValueError(f"dem.threads: {requested} is not a thread count (1 or more)")
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    cores = min(cores, nb.config.NUMBA_NUM_THREADS)
    if requested > cores:
        log.warning("dem.threads: %d asked, only %d cores available to this run: using %d", requested, cores, cores)
        return cores
    return requested


def _start_threads(threads: int) -> None:
    """Numba threads for _advance_threaded, on OpenMP unless the user chose a threading layer: it
    starts a parallel region in ~1.5 us here against ~35 us for TBB and ~55 us for numba's own
    workqueue, and the engine starts two regions per time step."""
    if not any(key in os.environ for key in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY")):
        nb.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
    nb.set_num_threads(min(threads, nb.config.NUMBA_NUM_THREADS))


def run(
    state: State,
    law: ContactLaw,
    walls: tuple,
    box: tuple,
    dt: float,
    n_steps: int,
    label: str = "",
    gravity: float = GRAVITY,
    threads: int = 1,
) -> None:
    """Advance `state` by n_steps of dt (s). walls = (x_left, x_right, y_floor, x_gate (m)
    [, gate_lift_speed (m/s), 0 when absent]);
    box = (x_min, x_max, y_min, y_max) (m) outside which a grain means blow-up.
    threads: 1 runs the serial kernel; more split the grains into that many chunks, one per
    thread (see _advance_threaded: the bits depend on the thread count, the physics does not).
    Raises SimulationError naming `label` and the step."""
    if state.x_built is None:
        state.pairs = build_pairs(state.x, state.radius, state.skin, *state.pairs)
        state.x_built = state.x.copy()
    walls = np.array(tuple(walls) + (0.0,) * (5 - len(walls)), np.float64)
    if threads > 1:
        _start_threads(threads)
        advance, chunks = _advance_threaded, (int(threads),)
    else:
        advance, chunks = _advance, ()
    status, done, start, partner, history, rebuilds, worst = advance(
        state.x,
        state.v,
        state.spin,
        state.radius,
        state.mass,
        state.x_built,
        state.skin,
        *state.pairs,
        state.wall_history,
        law.as_array(),
        walls,
        np.asarray(box, np.float64),
        float(state.time),
        float(dt),
        int(n_steps),
        float(gravity),
        *chunks,
    )
    state.pairs = (start, partner, history)
    state.steps += done
    state.time += done * dt
    state.rebuilds += rebuilds
    if status != OK:
        raise SimulationError(
            f"{label or 'simulation'}: blew up at step {state.steps} "
            f"(t = {state.steps * dt:.6g} s): {STATUS_TEXT[status]}"
        )


def frame_steps(interval: float, max_dt: float) -> tuple[int, float]:
    """Steps per output interval and the step (s) that divides it exactly, never above max_dt."""
    steps = max(1, math.ceil(interval / max_dt - 1e-9))
    return steps, interval / steps


@dataclass
class RunStats:
    steps: int = 0
    wall_time: float = 0.0
    particle_steps_per_second: float = 0.0
    extra: dict = field(default_factory=dict)


def record(
    state: State,
    law: ContactLaw,
    walls: tuple,
    box: tuple,
    dt_max: float,
    interval: float,
    n_frames: int,
    label: str = "",
    progress: Callable[[float], None] | None = None,
    threads: int = 1,
    frames: np.ndarray | None = None,
    after_frame: Callable[[int, np.ndarray], None] | None = None,
) -> tuple[np.ndarray, RunStats]:
    """Frames [n_frames, N, 2] (float32, m) every `interval` s, the first at the current state;
    threads as in `run`. To resume, `frames` holds the frames recorded so far and the state is at
    the last of them (state.time / interval frames after the first; NaN in those not yet recorded).
    after_frame(k, frames): called once frame k is recorded (a checkpoint)."""
    steps, dt = frame_steps(interval, dt_max)
    first = 1
    if frames is None:
        frames = np.full((n_frames, len(state.radius), 2), np.nan, np.float32)
        frames[0] = state.x
    else:
        first = round(state.time / interval) + 1
    t0, s0 = time.perf_counter(), state.steps
    for k in range(first, n_frames):
        run(state, law, walls, box, dt, steps, label=f"{label} frame {k}", threads=threads)
        frames[k] = state.x
        if after_frame is not None:
            after_frame(k, frames)
        if progress is not None:
            progress(k / (n_frames - 1))
    elapsed = time.perf_counter() - t0
    done = state.steps - s0
    stats = RunStats(
        steps=done,
        wall_time=elapsed,
        particle_steps_per_second=done * len(state.radius) / max(elapsed, 1e-12),
        extra={"dt": dt, "threads": threads},
    )
    return frames, stats


def mechanical_energy(state: State, law: ContactLaw, walls: tuple, gravity: float = GRAVITY) -> float:
    """Kinetic + gravitational + normal-spring energy (J) of `state` against `walls`.

    Tangential springs are left out: the energy check runs frictionless (mu = 0), where they
    carry no force. Used by the physics tests and benchmarks.
    """
    from scipy.spatial import cKDTree

    x, r = state.x, state.radius
    energy = state.kinetic_energy() + float(np.sum(state.mass * gravity * x[:, 1]))
    pairs = cKDTree(x).query_pairs(2 * r.max(), output_type="ndarray")
    if len(pairs):
        gap = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) - r[pairs[:, 0]] - r[pairs[:, 1]]
        energy += 0.5 * law.kn * float(np.sum(np.minimum(gap, 0.0) ** 2))
    x_left, x_right, y_floor, x_gate = walls[:4]
    for gap in (x[:, 0] - x_left - r, x_right - x[:, 0] - r, x[:, 1] - y_floor - r, x_gate - x[:, 0] - r):
        energy += 0.5 * law.kn * float(np.sum(np.minimum(gap, 0.0) ** 2))
    return energy
