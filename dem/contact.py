"""Contact law: linear spring-dashpot with tangential history and a Coulomb limit.

Pure functions of overlap and relative velocity (jax-md style), compiled with numba and lifted
over particle pairs and particle-wall pairs by dem.forces. The same law in every engine
(ARCHITECTURE.md, "Engines"): kn (N/m), kt = ratio * kn, normal damping from restitution,
tangential damping = ratio * normal damping, Coulomb friction mu |Fn|.

Sign conventions: `overlap` > 0 in contact (m); `normal_speed` > 0 when approaching (m/s);
`tangential_speed` is the slip speed of the contact point along the tangent (m/s).
"""

from __future__ import annotations

import math

from dem.kernel_sources import kernel

# Plain IEEE arithmetic, no fastmath: reassociation and fused multiply-adds are compiled by the
# processor's vector width and instruction set, so with them one case gave other bits on another
# machine (and a chaotic collapse another runout). Without them every x86-64 target gives the same
# bits (tests/test_physics.py), for about 12% more time a run. sqrt, the one function the kernels
# call, is exact in IEEE.
FAST_MATH = False


def restitution_factor(restitution: float) -> float:
    """|ln e| / sqrt(pi^2 + ln^2 e): normal damping is 2 sqrt(m_eff kn) times this."""
    log_e = math.log(restitution)
    return abs(log_e) / math.sqrt(math.pi**2 + log_e**2)


@kernel(inline="always", fastmath=FAST_MATH)
def normal_damping(m_eff: float, kn: float, restitution_factor: float) -> float:
    """eta_n (kg/s) = 2 sqrt(m_eff kn) |ln e| / sqrt(pi^2 + ln^2 e)."""
    return 2.0 * math.sqrt(m_eff * kn) * restitution_factor


@kernel(inline="always", fastmath=FAST_MATH)
def normal_force(overlap: float, normal_speed: float, kn: float, eta_n: float) -> float:
    """Repulsive normal force magnitude (N). Not clamped at zero (as LIGGGHTS hooke and MFIX),
    so a linear spring-dashpot pair separates with exactly e times its approach speed."""
    return kn * overlap + eta_n * normal_speed


@kernel(inline="always", fastmath=FAST_MATH)
def tangential_force(
    spring: float,
    tangential_speed: float,
    dt: float,
    kt: float,
    eta_t: float,
    friction: float,
    normal_force_magnitude: float,
) -> tuple[float, float]:
    """Tangential force (N) on the first body along the tangent, and the updated spring (m).

    The spring stretches by the slip of the contact point. Below the Coulomb limit the force is
    spring plus dashpot; at the limit the spring is shortened so that kt |spring| = mu |Fn| and
    the dashpot is dropped (LIGGGHTS `tangential history`), which keeps the history consistent.
    """
    spring = spring + tangential_speed * dt
    limit = friction * abs(normal_force_magnitude)
    spring_force = kt * abs(spring)
    if spring_force > limit:
        if spring != 0.0:
            spring = math.copysign(limit / kt, spring)
        return -kt * spring, spring
    return -kt * spring - eta_t * tangential_speed, spring


@kernel(inline="always", fastmath=FAST_MATH)
def cohesion_force(work_of_adhesion: float, r_eff: float) -> float:
    """Attractive force (N) while in contact: the JKR pull-off force 1.5 pi w R*.

    A constant attraction on top of the linear spring: a pair (or a grain on a wall) held by it
    separates only when pulled harder than 1.5 pi w R*, the JKR pull-off force.
    """
    return 1.5 * math.pi * work_of_adhesion * r_eff


@kernel(inline="always", fastmath=FAST_MATH)
def rolling_torque(
    torque: float,
    relative_spin: float,
    dt: float,
    kn: float,
    rolling_friction: float,
    r_eff: float,
    normal_force_magnitude: float,
) -> float:
    """Type-C elastic-plastic rolling resistance (EPSD2, as LIGGGHTS `rolling_friction epsd2`).

    A rotational spring kr = 2.25 kn mu_r^2 R*^2 loaded by the relative rotation, capped at
    mu_r R* |Fn|. Returns the new torque (N m) on the first body (the second gets minus it).
    relative_spin = spin_i - spin_j (rad/s).
    """
    kr = 2.25 * kn * rolling_friction * rolling_friction * r_eff * r_eff
    torque = torque - kr * relative_spin * dt
    limit = rolling_friction * r_eff * abs(normal_force_magnitude)
    if abs(torque) > limit:
        torque = math.copysign(limit, torque)
    return torque
