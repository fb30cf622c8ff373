"""The builtin engine's collapse run: settle behind the gate, remove it at t = 0, record frames."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dem.case import CollapseCase
from dem.integrate import ENGINE_VERSION, ContactLaw, State, record
from dem.packing import blowup_box, check_grain_count, settle_column, walls_open
from dem.trajectory import GRAIN, Trajectory, engine_attrs


def state_from_packing(case: CollapseCase, packing: Trajectory) -> State:
    """Grains at rest at the last frame of `packing` (a settled-column trajectory): positions (m),
    radii (m), masses from case.density (kg/m^3)."""
    check_grain_count(case, packing)
    return State.at_rest(packing.positions[-1], packing.radius, case.density)


def simulate_collapse(
    case: CollapseCase,
    packing: Trajectory | None = None,
    progress: Callable[[float], None] | None = None,
    threads: int = 1,
) -> Trajectory:
    """Collapse trajectory: case.n_frames frames every case.frame_interval, gate removed at t = 0.

    packing: the settled column (dem.packing.settle_column); settled here when None.
    progress: callable(fraction_done) or None.
    threads: as in dem.integrate.run (recorded: the trajectory's bits depend on it).
    """
    if packing is None:
        packing = settle_column(case, threads=threads)
    state = state_from_packing(case, packing)
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
    )
    attrs = engine_attrs(case, "builtin", ENGINE_VERSION)
    attrs.update(
        dt=stats.extra["dt"],
        steps=stats.steps,
        wall_time_s=stats.wall_time,
        particle_steps_per_second=stats.particle_steps_per_second,
        threads=threads,
        settled_height=packing.attrs.get("settled_height", np.nan),
    )
    return Trajectory(
        positions=frames,
        radius=packing.radius.copy(),
        particle_type=np.full(packing.n_particles, GRAIN, np.int32),
        attrs=attrs,
    )
