"""The initial column: grains poured on a jittered lattice behind the gate, settled at rest.

Diameters are uniform in d (1 +- polydispersity), about +-10% by default, so that the 2D packing
does not crystallise. Grains start on a triangular lattice whose pitch clears the largest grain,
with a random jitter, so nothing overlaps; gravity then settles them against the floor, the left
wall and the gate at x = L_i, with the case's own contact law. Deterministic for a given seed.

The settled column is a one-frame trajectory (engine "builtin", stage "settled"), so every
engine can start from the same packing and it is stored and read like any other trajectory; inside
dem.run_store.kept_runs (a long job's block) a packing settled before is read from the store.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from dem.case import FILL_HEIGHT_FACTOR, MAX_DT_OVER_CONTACT_TIME, CaseError, CollapseCase
from dem.forces import ContactLaw
from dem.integrate import ENGINE_VERSION, SimulationError, State, run
from dem.run_store import active_store, run_key
from dem.trajectory import GRAIN, Trajectory, TrajectoryError, engine_attrs

LATTICE_CLEARANCE = 1.02  # lattice pitch / largest diameter
REST_SPEED = 1e-3  # settled when the RMS grain speed is below this fraction of sqrt(g H_i)
SETTLE_CHECK_TSTAR = 0.05  # check for rest every this many t*
MAX_SETTLE_TSTAR = 20.0  # give up (error) after this many t*
# Settling steps 2.5 times longer than the collapse's (contact_time / 20 at the default / 50), never
# longer than contact_time / 10, the case's own stability bound (MAX_DT_OVER_CONTACT_TIME): only the
# state at rest is kept, and 10-20 steps still resolve a contact (symplectic Euler is stable to
# ~contact_time / 1.6). The settle then costs about half to two thirds of what 1 t* of collapse
# costs at either step (docs/experiments/dem-speed.md, benchmarks/builtin_engine.py); most of its ~1.7 t* is the lattice
# falling ~0.2 H_i and a few grains splashed off the top falling back.
SETTLE_STEP_OVER_COLLAPSE_STEP = 2.5
MIN_SETTLE_STEPS_PER_CONTACT = 1.0 / MAX_DT_OVER_CONTACT_TIME


def grain_radii(case: CollapseCase, rng: np.random.Generator) -> np.ndarray:
    """[N] radii (m), uniform in d/2 (1 +- polydispersity)."""
    spread = case.polydispersity
    return 0.5 * case.diameter * rng.uniform(1 - spread, 1 + spread, case.n_particles)


def pour_column(case: CollapseCase) -> tuple[np.ndarray, np.ndarray]:
    """Non-overlapping start: positions [N, 2] (m) on a jittered triangular lattice in
    [0, L_i] x [0, FILL_HEIGHT_FACTOR H_i], radius [N] (m)."""
    rng = np.random.default_rng(case.seed)
    radius = grain_radii(case, rng)
    d_max = 2 * radius.max()
    pitch = LATTICE_CLEARANCE * d_max
    row_height = pitch * math.sqrt(3) / 2
    per_row = int((case.L_i - d_max) / pitch) + 1
    sites = []
    row = 0
    while len(sites) < case.n_particles:
        offset = 0.5 * pitch * (row % 2)
        for k in range(per_row - (row % 2)):
            sites.append((0.5 * d_max + offset + k * pitch, 0.5 * d_max + row * row_height))
        row += 1
    positions = np.array(sites[: case.n_particles])
    top = positions[:, 1].max() + 0.5 * d_max
    if top > FILL_HEIGHT_FACTOR * case.H_i:
        raise CaseError(
            f"solid_fraction: {case.n_particles} grains of {case.material.name} need a pour of "
            f"{top:.4g} m, over {FILL_HEIGHT_FACTOR} x H_i; lower solid_fraction or polydispersity"
        )
    # jitter within the clearance left by each grain's own size
    slack = np.maximum(0.5 * pitch - radius, 0.0)[:, None]
    positions = positions + rng.uniform(-1, 1, positions.shape) * slack * 0.5
    order = np.lexsort((positions[:, 0], positions[:, 1]))
    return positions[order], radius[order]


def walls_with_gate(case: CollapseCase) -> tuple:
    """(x_left, x_right, y_floor, x_gate) in m, gate closed at L_i."""
    return (0.0, case.box_width, 0.0, case.L_i)


def walls_open(case: CollapseCase) -> tuple:
    """Walls from t = 0: the gate is gone, or its lower edge rises at case.gate_lift_speed (m/s)."""
    if case.gate_lift_speed > 0:
        return (0.0, case.box_width, 0.0, case.L_i, case.gate_lift_speed)
    return (0.0, case.box_width, 0.0, math.inf)


def blowup_box(case: CollapseCase) -> tuple:
    """Bounds (m) outside which a grain means the run blew up."""
    margin = case.diameter
    return (-margin, case.box_width + margin, -margin, case.box_height + margin)


def settle_time_step(case: CollapseCase) -> float:
    """Settling time step (s): SETTLE_STEP_OVER_COLLAPSE_STEP collapse steps, at most contact_time / 10."""
    # written as steps per contact so that the default's is contact_time / 20.0 exactly (1 / 0.02 is
    # 50.0 in floating point): its packings keep their bits
    collapse_steps_per_contact = 1.0 / case.dt_over_contact_time
    steps_per_contact = max(MIN_SETTLE_STEPS_PER_CONTACT, collapse_steps_per_contact / SETTLE_STEP_OVER_COLLAPSE_STEP)
    return case.contact_time / steps_per_contact


def settle_state(case: CollapseCase, progress: Callable[[float], None] | None = None, threads: int = 1) -> State:
    """Pour and settle the column behind the gate; the settled State (velocities near zero).
    threads: as in dem.integrate.run."""
    positions, radius = pour_column(case)
    state = State.at_rest(positions, radius, case.density)
    law = ContactLaw.from_case(case)
    chunk = SETTLE_CHECK_TSTAR * case.t_star
    dt = settle_time_step(case)
    steps = max(1, math.ceil(chunk / dt))
    rest_speed = REST_SPEED * math.sqrt(9.81 * case.H_i)
    for k in range(int(MAX_SETTLE_TSTAR / SETTLE_CHECK_TSTAR)):
        run(
            state,
            law,
            walls_with_gate(case),
            blowup_box(case),
            dt,
            steps,
            label=f"case {case.name or '?'} settling",
            threads=threads,
        )
        # RMS, not max: a lone rattler in a pore can keep bouncing long after the column is at rest
        speed = float(np.sqrt(np.mean(np.sum(state.v**2, axis=1) + (state.spin * state.radius) ** 2)))
        if progress is not None:
            progress(min(1.0, rest_speed / max(speed, 1e-30)))
        if k >= 2 and speed < rest_speed:
            break
    else:
        raise SimulationError(
            f"case {case.name or '?'}: column not at rest after {MAX_SETTLE_TSTAR} t* of "
            f"settling (RMS speed {speed:.3g} m/s)"
        )
    state.v[:] = 0.0
    state.spin[:] = 0.0
    return state


def settle_column(case: CollapseCase, progress: Callable[[float], None] | None = None, threads: int = 1) -> Trajectory:
    """The settled column as a one-frame Trajectory (engine "builtin", stage "settled").
    threads: as in dem.integrate.run (recorded: the packing's bits depend on it). Inside
    dem.run_store.kept_runs: the packing of the same case and thread count settled before, read from
    the store (progress(1.0)), else settled and stored (and read back: the same bits either way)."""
    store = active_store()
    if store is None:
        return settled_column(case, progress, threads)
    key = run_key("packing", case=case.to_dict(), threads=threads)
    return store.kept(key, lambda _work_dir: settled_column(case, progress, threads), progress)


def settled_column(case: CollapseCase, progress: Callable[[float], None] | None = None, threads: int = 1) -> Trajectory:
    """settle_column's packing, settled here and now (no store)."""
    state = settle_state(case, progress, threads)
    attrs = engine_attrs(case, "builtin", ENGINE_VERSION)
    attrs.update(
        stage="settled",
        settled_height=float(np.max(state.x[:, 1] + state.radius)),
        settle_steps=state.steps,
        threads=threads,
    )
    return Trajectory(
        positions=state.x[None].astype(np.float32),
        radius=state.radius.copy(),
        particle_type=np.full(len(state.radius), GRAIN, np.int32),
        attrs=attrs,
    )


def check_grain_count(case: CollapseCase, packing: Trajectory) -> None:
    """TrajectoryError unless `packing` (a settled column) holds exactly the case's
    case.n_particles grains: a packing settled for another case must not start this one."""
    if packing.n_particles != case.n_particles:
        raise TrajectoryError(
            f"packing has {packing.n_particles} grains, case {case.name or '?'} needs "
            f"{case.n_particles}: it was settled for another case"
        )
