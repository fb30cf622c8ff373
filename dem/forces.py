"""The builtin engine's forces: the contact law (dem.contact) summed over each grain's pairs and
walls, gravity, and the drag of a quasi-2D channel's side walls.

The kernels take the contact law as one float array (ContactLaw.as_array, indexed by KN ...
SIDEWALL) and the walls as walls = (x_left, x_right, y_floor, x_gate, gate_lift_speed) (m, m/s).
`_contact` is one contact, a pure function of the overlap, the relative motion and the history;
`_contact_forces` lifts it over the pairs (i, j > i) and the N_WALLS walls of a range of grains.
`_forces` fills every grain's force for one serial step, `_range_forces` one thread's range of
them (dem.integrate._advance_threaded, which adds the side walls, `_sidewall_drag`, once the
other ranges' reactions are in). Units SI throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dem.case import CollapseCase
from dem.contact import (
    FAST_MATH,
    cohesion_force,
    normal_damping,
    normal_force,
    restitution_factor,
    rolling_torque,
    tangential_force,
)
from dem.kernel_sources import kernel

N_WALLS = 4  # left, right, floor, gate

# Indices into the contact-law array the compiled kernel takes.
KN, KT, ETA_RATIO, E_FACTOR, E_FACTOR_WALL, MU, MU_WALL, MU_BASE, MU_ROLL, ADHESION, SIDEWALL = range(11)


@dataclass
class ContactLaw:
    """Contact parameters as the compiled kernel takes them (SI units)."""

    kn: float
    kt: float
    tangential_damping_ratio: float
    restitution_factor: float  # particle-particle, see dem.contact.restitution_factor
    restitution_factor_wall: float
    friction: float
    friction_wall: float  # left, right walls and gate
    friction_base: float = -1.0  # floor; < 0: same as friction_wall
    rolling_friction: float = 0.0  # EPSD2 mu_r, pairs and walls
    cohesion_energy: float = 0.0  # work of adhesion w (J/m^2)
    sidewall_friction_per_width: float = 0.0  # mu_sw / channel width (1/m)

    @classmethod
    def from_case(cls, case: CollapseCase) -> ContactLaw:
        return cls(
            kn=case.normal_stiffness,
            kt=case.tangential_stiffness_ratio * case.normal_stiffness,
            tangential_damping_ratio=case.tangential_damping_ratio,
            restitution_factor=restitution_factor(case.restitution),
            restitution_factor_wall=restitution_factor(case.resolved_restitution_wall),
            friction=case.friction,
            friction_wall=case.resolved_friction_wall,
            friction_base=case.resolved_friction_base,
            rolling_friction=case.rolling_friction,
            cohesion_energy=case.cohesion_energy,
            sidewall_friction_per_width=case.sidewall_friction / case.channel_width,
        )

    def as_array(self) -> np.ndarray:
        base = self.friction_wall if self.friction_base < 0 else self.friction_base
        return np.array(
            [
                self.kn,
                self.kt,
                self.tangential_damping_ratio,
                self.restitution_factor,
                self.restitution_factor_wall,
                self.friction,
                self.friction_wall,
                base,
                self.rolling_friction,
                self.cohesion_energy,
                self.sidewall_friction_per_width,
            ]
        )


@kernel(inline="always", fastmath=FAST_MATH)
def _contact(
    overlap,
    nx,
    ny,
    rvx,
    rvy,
    slip,
    spin_rel,
    r_eff,
    m_eff,
    spring,
    roll,
    dt,
    kn,
    kt,
    eta_ratio,
    ce,
    mu,
    mu_roll,
    adhesion,
):
    """One contact with unit normal (nx, ny) from the first body to the second.

    Returns force (fx, fy) on the first body, its tangential force, the rolling torque on it,
    |Fn| and the new history (spring, roll)."""
    eta_n = normal_damping(m_eff, kn, ce)
    fn = normal_force(overlap, rvx * nx + rvy * ny, kn, eta_n)
    if adhesion > 0.0:
        fn -= cohesion_force(adhesion, r_eff)
    ft, spring = tangential_force(spring, slip, dt, kt, eta_ratio * eta_n, mu, fn)
    if mu_roll > 0.0:
        roll = rolling_torque(roll, spin_rel, dt, kn, mu_roll, r_eff, fn)
    return -fn * nx - ft * ny, -fn * ny + ft * nx, ft, roll, abs(fn), spring


@kernel(fastmath=FAST_MATH)
def _contact_forces(
    i_start,
    i_end,
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
    time,
    dt,
    force,
    torque,
    load,
    spill_force,
    spill_torque,
    spill_load,
):
    """Add the contact forces of grains i_start <= i < i_end, their pairs (i, j > i) to both
    grains and their walls, to force [N, 2] (N), torque [N] (N m) and load [N] (sum of |Fn|, N);
    the reaction on a grain j >= i_end goes to spill_force, spill_torque, spill_load instead.
    Updates the history of those pairs and walls, which no other range touches.
    walls = (x_left, x_right, y_floor, x_gate, gate_lift_speed). Returns the largest overlap / diameter."""
    # parameters as locals: the compiler cannot hoist reads of `law` past stores to `history`
    kn, kt, eta_ratio, ce, ce_wall = law[KN], law[KT], law[ETA_RATIO], law[E_FACTOR], law[E_FACTOR_WALL]
    mu, mu_wall, mu_base, mu_roll, adhesion = law[MU], law[MU_WALL], law[MU_BASE], law[MU_ROLL], law[ADHESION]
    x_left, x_right, y_floor, x_gate, gate_speed = walls[0], walls[1], walls[2], walls[3], walls[4]
    # the gate's lower edge rises at gate_speed from the floor; grains below it are free
    gate_bottom = gate_speed * time if gate_speed > 0.0 else -np.inf
    worst = 0.0
    for i in range(i_start, i_end):
        xi, yi, ri = x[i, 0], x[i, 1], radius[i]
        for k in range(start[i], start[i + 1]):
            j = partner[k]
            dx = x[j, 0] - xi
            dy = x[j, 1] - yi
            reach = ri + radius[j]
            dist2 = dx * dx + dy * dy
            if dist2 >= reach * reach:
                history[k, 0] = 0.0  # out of contact: the history is forgotten
                history[k, 1] = 0.0
                continue
            dist = math.sqrt(dist2)
            nx, ny = dx / dist, dy / dist  # unit normal from i to j
            overlap = reach - dist
            if overlap > 2.0 * worst * min(ri, radius[j]):  # a division only for a new worst
                worst = overlap / (2.0 * min(ri, radius[j]))
            rvx = v[i, 0] - v[j, 0]
            rvy = v[i, 1] - v[j, 1]
            slip = rvx * (-ny) + rvy * nx + spin[i] * ri + spin[j] * radius[j]
            fx, fy, ft, roll, fn, history[k, 0] = _contact(
                overlap,
                nx,
                ny,
                rvx,
                rvy,
                slip,
                spin[i] - spin[j],
                ri * radius[j] / reach,
                mass[i] * mass[j] / (mass[i] + mass[j]),
                history[k, 0],
                history[k, 1],
                dt,
                kn,
                kt,
                eta_ratio,
                ce,
                mu,
                mu_roll,
                adhesion,
            )
            history[k, 1] = roll
            force[i, 0] += fx
            force[i, 1] += fy
            torque[i] += ri * ft + roll
            load[i] += fn
            if j < i_end:
                force[j, 0] -= fx
                force[j, 1] -= fy
                torque[j] += radius[j] * ft - roll
                load[j] += fn
            else:  # a grain of a later range: its own range's thread may be writing `force`
                spill_force[j, 0] -= fx
                spill_force[j, 1] -= fy
                spill_torque[j] += radius[j] * ft - roll
                spill_load[j] += fn
        # walls: left, right, floor, gate (x_gate = +inf once removed); m_eff = m, R* = r.
        # Most grains touch none: the same tests as the loop's (overlap <= 0 there is r <= gap here)
        if ri <= xi - x_left and ri <= x_right - xi and ri <= yi - y_floor and (yi < gate_bottom or ri <= x_gate - xi):
            for w in range(N_WALLS):
                wall_history[i, w, 0] = 0.0
                wall_history[i, w, 1] = 0.0
            continue
        for w in range(N_WALLS):
            mu_w = mu_wall
            if w == 0:
                overlap, nx, ny = ri - (xi - x_left), -1.0, 0.0
            elif w == 1:
                overlap, nx, ny = ri - (x_right - xi), 1.0, 0.0
            elif w == 2:
                overlap, nx, ny = ri - (yi - y_floor), 0.0, -1.0
                mu_w = mu_base
            else:
                overlap, nx, ny = ri - (x_gate - xi), 1.0, 0.0
                if yi < gate_bottom:
                    overlap = 0.0
            if overlap <= 0.0:
                wall_history[i, w, 0] = 0.0
                wall_history[i, w, 1] = 0.0
                continue
            worst = max(worst, overlap / (2.0 * ri))
            slip = v[i, 0] * (-ny) + v[i, 1] * nx + spin[i] * ri
            fx, fy, ft, roll, fn, wall_history[i, w, 0] = _contact(
                overlap,
                nx,
                ny,
                v[i, 0],
                v[i, 1],
                slip,
                spin[i],
                ri,
                mass[i],
                wall_history[i, w, 0],
                wall_history[i, w, 1],
                dt,
                kn,
                kt,
                eta_ratio,
                ce_wall,
                mu_w,
                mu_roll,
                adhesion,
            )
            wall_history[i, w, 1] = roll
            force[i, 0] += fx
            force[i, 1] += fy
            torque[i] += ri * ft + roll
            load[i] += fn
    return worst


@kernel(fastmath=FAST_MATH)
def _sidewall_drag(i_start, i_end, v, radius, load, law, gravity, force):
    """Subtract from force [N, 2] (N) the side-wall drag of grains i_start <= i < i_end, moving at
    v [N, 2] (m/s) with radius [N] (m) and contact load [N] (sum of |Fn|, N); nothing when
    law[SIDEWALL] (mu_sw / channel width, 1/m) is 0.

    The front and back walls of a quasi-2D channel: Coulomb friction against the motion, loaded in
    proportion to the grain's contact load and its share d / W of the channel width."""
    sidewall = law[SIDEWALL]
    if sidewall > 0.0:
        v_reg = 1e-3 * math.sqrt(gravity * radius[0])  # regularises the direction at rest
        for i in range(i_start, i_end):
            speed = math.sqrt(v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1])
            drag = sidewall * 2.0 * radius[i] * load[i] / max(speed, v_reg)
            force[i, 0] -= drag * v[i, 0]
            force[i, 1] -= drag * v[i, 1]


@kernel(fastmath=FAST_MATH)
def _forces(
    x, v, spin, radius, mass, start, partner, history, wall_history, law, walls, time, dt, gravity, force, torque, load
):
    """Fill force [N, 2] (N), torque [N] (N m) and contact load [N] (sum of |Fn|, N) from gravity,
    the contacts and the side walls; update the contact history.
    walls = (x_left, x_right, y_floor, x_gate, gate_lift_speed). Returns the largest overlap / diameter."""
    n = x.shape[0]
    for i in range(n):
        force[i, 0] = 0.0
        force[i, 1] = -mass[i] * gravity
        torque[i] = 0.0
        load[i] = 0.0
    worst = _contact_forces(
        0,
        n,
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
        time,
        dt,
        force,
        torque,
        load,
        force,
        torque,
        load,
    )
    _sidewall_drag(0, n, v, radius, load, law, gravity, force)
    return worst


@kernel(fastmath=FAST_MATH)
def _range_forces(
    i_start,
    i_end,
    i_reach,
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
    time,
    dt,
    gravity,
    force,
    torque,
    load,
    spill_force,
    spill_torque,
    spill_load,
):
    """`_forces` without the side walls for the grains i_start <= i < i_end of one thread: sets
    their force, torque and load from gravity and their contacts, and the spill buffers of the
    grains up to i_reach (see _contact_forces). Returns the largest overlap / diameter."""
    for i in range(i_start, i_end):
        force[i, 0] = 0.0
        force[i, 1] = -mass[i] * gravity
        torque[i] = 0.0
        load[i] = 0.0
    for i in range(i_end, i_reach):
        spill_force[i, 0] = 0.0
        spill_force[i, 1] = 0.0
        spill_torque[i] = 0.0
        spill_load[i] = 0.0
    return _contact_forces(
        i_start,
        i_end,
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
        time,
        dt,
        force,
        torque,
        load,
        spill_force,
        spill_torque,
        spill_load,
    )
