"""LIGGGHTS 3.8 with a contact law and a packing of its own: data from another solver.

The project's LIGGGHTS deck (dem/engines/liggghts.py) reproduces the builtin physics. This one
differs from it on purpose: it makes the "measured" data of the diagnosis' generalisation test
(calibration/synthetic.py, liggghts_measurement), which must not come from the model the diagnosis
fits. It is not an engine of the pipeline (not in dem.engines.ENGINES).

- Contact law: `pair_style gran model hertz tangential history`: Hertz normal force
  4/3 E* sqrt(R*) delta^1.5 with damping set by the restitution coefficient e, Mindlin tangential
  spring 8 G* sqrt(R* delta) capped at mu |Fn|; plus `cohesion sjkr` (an attraction k A while in
  contact, A ~ 2 pi R* delta the contact area, k the cohesion energy density; the LIGGGHTS docs say
  it is derived for the Hertzian style, with Hooke it only softens the spring) and
  `rolling_friction epsd2`. No size classes: LIGGGHTS computes the Hertz damping per contact.
- E (one value for grains and walls, hertz_parameters): the softest that keeps a mean pair's overlap
  at rest within MAX_OVERLAP of d under the largest load it carries: the weight of a stack of
  H_i / d grains (a bound on the column's weight on one contact) or, with cohesion, the SJKR pull
  at rest (a cohesive pair rests where Hertz balances SJKR, at 9/4 of the pull-off overlap, where
  the Hertz force is 27/4 of the pull-off force). Softer is cheaper: the Hertz contact time grows
  as E^-2/5, so the time step is as long as small overlaps allow.
- Cohesion: the case's cohesion_energy w states the pull-off force of a mean pair, 1.5 pi w R*
  (the builtin's JKR value, dem.contact.cohesion_force; a Bond number in calibration.mechanisms);
  the deck gives SJKR the k whose Hertz + SJKR pull-off force of a mean pair is that force
  (sjkr_energy_density). Walls get the same k.
- Types: 1 grains, 2 the left and right walls and the gate, 3 the floor (its own friction:
  case.friction_base). Rolling friction on every contact, as the builtin's.
- Packing: the case's grains (count and diameters, seed case.seed) on dem.packing.pour_column's
  jittered triangular lattice, settled by LIGGGHTS in the same deck behind a gate wall at x = L_i
  until at rest (RMS translational speed below dem.packing.REST_SPEED sqrt(g H_i), checked every
  SETTLE_CHECK_TSTAR t*); then the gate is removed (unfix), the time reset and the collapse dumped
  every frame interval. A column still moving after MAX_SETTLE_TSTAR t* is an EngineError.
- One layer of spheres at z = 0, as dem/engines/liggghts.py (no enforce2d: read why there).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dem.case import GRAVITY, CollapseCase, sphere_mass
from dem.contact import cohesion_force
from dem.engines.base import EngineError, read_error, refuse_unsupported
from dem.engines.liggghts import DATA, DUMP_COLUMNS, FRAMES, LOG, LiggghtsEngine, _matrix_lines
from dem.integrate import frame_steps
from dem.packing import MAX_SETTLE_TSTAR, REST_SPEED, pour_column
from dem.trajectory import GRAIN, Trajectory

SUPPORTED = ("rolling_friction", "cohesion_energy", "friction_base")
POISSON_RATIO = 0.25  # of grains and walls; with E it sets the Mindlin tangential stiffness 8 G* sqrt(R* delta)
MAX_OVERLAP = 0.01  # largest resting overlap of a mean pair, in mean diameters
SETTLE_CHECK_TSTAR = 0.25  # the settle checks for rest every this many t* (one LIGGGHTS `run` each)
HERTZ_CONTACT_TIME = 2.868  # t_c = 2.868 (m*^2 / (R* E*^2 v))^(1/5), an elastic Hertz impact at speed v
SETTLED = re.compile(r"^settle: kinetic energy (\S+) J at step (\d+), at rest below (\S+) J", re.M)


@dataclass(frozen=True)
class HertzParameters:
    """What the deck sets beyond the case: E (Pa) and nu of grains and walls, E* (Pa) of a contact,
    SJKR's cohesion energy density k (J/m^3, 0 without cohesion), the time step (s)."""

    youngs_modulus: float
    poisson_ratio: float
    effective_modulus: float
    cohesion_energy_density: float
    time_step: float


def sjkr_pull_off_force(energy_density: float, effective_modulus: float, r_eff: float) -> float:
    """Pull-off force (N) of a Hertz + SJKR contact: k (J/m^3), E* (Pa), R* (m).

    F(delta) = 4/3 E* sqrt(R*) delta^1.5 - 2 pi k R* delta (repulsion positive, A = 2 pi R* delta to
    first order) is least at sqrt(delta*) = pi k sqrt(R*) / E*, where F = -2/3 pi k R* delta*:
    pulled harder than 2/3 pi^3 k^3 R*^2 / E*^2, the pair comes apart.
    """
    return 2.0 / 3.0 * math.pi**3 * energy_density**3 * r_eff**2 / effective_modulus**2


def sjkr_energy_density(pull_off: float, effective_modulus: float, r_eff: float) -> float:
    """SJKR's k (J/m^3) whose Hertz + SJKR pull-off force is `pull_off` (N); the inverse of
    sjkr_pull_off_force."""
    return (1.5 * pull_off * effective_modulus**2 / (math.pi**3 * r_eff**2)) ** (1.0 / 3.0)


def hertz_parameters(case: CollapseCase) -> HertzParameters:
    """E, k and the time step of `case` (module docstring): E from the largest resting load of a
    mean pair (R* = d/4), the step case.dt_over_contact_time of the Hertz impact time of the
    lightest pair (diameter d (1 - polydispersity)) at the free-fall speed sqrt(2 g H_i), made to
    divide the frame interval."""
    d, r_eff = case.diameter, case.diameter / 4.0
    pull_off = cohesion_force(case.cohesion_energy, r_eff) if case.cohesion_energy > 0 else 0.0
    stack = case.H_i / d * case.sphere_mass(d) * GRAVITY
    load = max(stack, 27.0 / 4.0 * pull_off)
    # 4/3 E* sqrt(R*) delta^1.5 = load at delta = MAX_OVERLAP d
    e_star = 0.75 * load / (math.sqrt(r_eff) * (MAX_OVERLAP * d) ** 1.5)
    m_eff = 0.5 * case.sphere_mass(case.min_diameter)
    impact = math.sqrt(2.0 * GRAVITY * case.H_i)
    contact_time = HERTZ_CONTACT_TIME * (m_eff**2 / (case.min_diameter / 4.0 * e_star**2 * impact)) ** 0.2
    _, dt = frame_steps(case.frame_interval, case.dt_over_contact_time * contact_time)
    return HertzParameters(
        youngs_modulus=2.0 * (1.0 - POISSON_RATIO**2) * e_star,  # 1/E* = 2 (1 - nu^2) / E for like bodies
        poisson_ratio=POISSON_RATIO,
        effective_modulus=e_star,
        cohesion_energy_density=sjkr_energy_density(pull_off, e_star, r_eff) if pull_off > 0 else 0.0,
        time_step=dt,
    )


def poured_column(case: CollapseCase) -> Trajectory:
    """The unsettled start: dem.packing.pour_column's lattice (seed case.seed) as a one-frame
    Trajectory (positions [1, N, 2], radius [N], m)."""
    positions, radius = pour_column(case)
    return Trajectory(positions[None].astype(np.float32), radius, np.full(len(radius), GRAIN, np.int32), {})


def _per_type(name: str, value: float, n_types: int) -> str:
    """`value` for every atom type (peratomtype: v1 .. vn); type pairs: liggghts._matrix_lines."""
    return f"fix {name} all property/global {name} peratomtype " + " ".join([f"{value:.10g}"] * n_types)


def render_hertz_deck(case: CollapseCase, poured: Trajectory) -> tuple[str, str]:
    """(input script, data file) text: settle `poured` (its last frame) behind the gate, release,
    collapse with case.n_frames frames."""
    refuse_unsupported(case, "liggghts_hertz", SUPPORTED)
    hertz = hertz_parameters(case)
    positions = np.asarray(poured.positions[-1], float)
    radius = np.asarray(poured.radius, float)
    steps_per_frame, dt = frame_steps(case.frame_interval, hertz.time_step)
    n_steps = steps_per_frame * (case.n_frames - 1)
    check_steps = max(1, round(SETTLE_CHECK_TSTAR * case.t_star / dt))
    max_checks = math.ceil(MAX_SETTLE_TSTAR / SETTLE_CHECK_TSTAR)
    mass = sphere_mass(case.density, 2 * radius)
    rest_energy = float(0.5 * mass.sum() * REST_SPEED**2 * GRAVITY * case.H_i)  # RMS speed REST_SPEED sqrt(g H_i)
    depth = 2 * float(radius.max())
    data = [
        f"LIGGGHTS data: poured column of case {case.name or '?'} ({len(radius)} grains), settled by the deck",
        "",
        f"{len(radius)} atoms",
        "3 atom types",
        "",
        f"0 {case.box_width!r} xlo xhi",
        f"0 {case.box_height!r} ylo yhi",
        f"{-depth / 2!r} {depth / 2!r} zlo zhi",
        "",
        "Atoms",
        "",
    ]
    # id type diameter density x y z, as Python floats (repr gives the shortest text of the same float)
    for i, ((x, y), r) in enumerate(zip(positions.tolist(), radius.tolist()), start=1):
        data.append(f"{i} 1 {2 * r!r} {case.density!r} {x!r} {y!r} 0")
    friction = np.full((3, 3), case.resolved_friction_wall)
    friction[0, 0] = case.friction
    friction[:, 2] = friction[2, :] = case.resolved_friction_base
    restitution = np.full((3, 3), case.resolved_restitution_wall)
    restitution[0, 0] = case.restitution
    properties = [
        _per_type("youngsModulus", hertz.youngs_modulus, 3),
        _per_type("poissonsRatio", hertz.poisson_ratio, 3),
        _matrix_lines("coefficientRestitution", restitution),
        _matrix_lines("coefficientFriction", friction),
    ]
    model = "model hertz tangential history"  # keyword order: tangential, cohesion, rolling_friction
    if hertz.cohesion_energy_density > 0:
        model += " cohesion sjkr"
        properties.append(_matrix_lines("cohesionEnergyDensity", np.full((3, 3), hertz.cohesion_energy_density)))
    if case.rolling_friction > 0:
        model += " rolling_friction epsd2"
        properties.append(_matrix_lines("coefficientRollingFriction", np.full((3, 3), case.rolling_friction)))
    wall = f"all wall/gran {model} primitive type"
    properties = "\n".join(properties)
    deck = f"""# LIGGGHTS 3.8 input: 2D column collapse, Hertz contacts; rendered by dem/engines/liggghts_hertz.py
# case: {case.name or "?"}; {len(radius)} grains poured on a lattice ({DATA}), settled here behind a gate at x = L_i
# frames: {case.n_frames}
# E = {hertz.youngs_modulus:.4g} Pa (overlap at rest <= {MAX_OVERLAP:g} d); SJKR k = {hertz.cohesion_energy_density:.4g}
# type 1: grains; type 2: left and right walls and the gate; type 3: floor
atom_style      granular
atom_modify     map array
dimension       3
boundary        f fm f
newton          off
communicate     single vel yes
units           si
processors      * * 1
soft_particles  yes

read_data       {DATA}

neighbor        {0.4 * float(radius.mean())!r} bin
neigh_modify    delay 0

{properties}

pair_style      gran {model}
pair_coeff      * *

timestep        {dt!r}
fix gravity     all gravity {GRAVITY!r} vector 0.0 -1.0 0.0
fix floor       {wall} 3 yplane 0.0
fix left_wall   {wall} 2 xplane 0.0
fix right_wall  {wall} 2 xplane {case.box_width!r}
fix gate        {wall} 2 xplane {case.L_i!r}
fix integrate   all nve/sphere

thermo_style    custom step atoms ke cpu
thermo_modify   lost error norm no
thermo          {check_steps}

# settle: check for rest every {SETTLE_CHECK_TSTAR:g} t* ({check_steps} steps), twice at least, {max_checks} at most
variable        check loop {max_checks}
label           settle
run             {check_steps}
variable        ke_now equal ke
variable        step_now equal step
if "${{ke_now}} < {rest_energy!r} && ${{check}} >= 2" then "jump SELF settled"
next            check
jump            SELF settle
label           settled
print           "settle: kinetic energy ${{ke_now}} J at step ${{step_now}}, at rest below {rest_energy!r} J"
if "${{ke_now}} >= {rest_energy!r}" then "jump SELF end"

# release: the gate goes, the clock restarts, the collapse is dumped every frame interval
unfix           gate
reset_timestep  0
thermo          {max(1, n_steps // 20)}
dump            frames all custom {steps_per_frame} {FRAMES}/frame.*.txt {" ".join(DUMP_COLUMNS)}
dump_modify     frames sort id format "%d %d %.9g %.9g %.9g %.9g"
run             {n_steps}
label           end
"""
    return deck, "\n".join(data) + "\n"


def settle_record(log: str | os.PathLike) -> tuple[float, int, float] | None:
    """(kinetic energy (J), steps, rest threshold (J)) at the end of the settle, from the log's
    'settle:' line; None when the solver never got there."""
    log = Path(log)
    match = SETTLED.search(log.read_text(errors="replace")) if log.exists() else None
    if match is None:
        return None
    return float(match.group(1)), int(match.group(2)), float(match.group(3))


class LiggghtsHertzEngine(LiggghtsEngine):
    """LIGGGHTS with this module's deck; simulate(case, poured_column(case), work_dir)."""

    name = "liggghts_hertz"
    mechanisms = SUPPORTED

    def render_files(self, case: CollapseCase, packing: Trajectory) -> tuple[str, str]:
        """(input script, data file) text: render_hertz_deck."""
        return render_hertz_deck(case, packing)

    def run(self, deck: Path, progress: Callable[[float], None] | None = None) -> None:
        """Run the deck; a column that never came to rest fails with an EngineError naming its
        kinetic energy (the deck then releases nothing, so the frame count fails too)."""
        deck = Path(deck)
        try:
            super().run(deck, progress)
        except EngineError as exc:
            settled = settle_record(deck.parent / LOG)
            if settled is not None and settled[0] >= settled[2]:
                energy, steps, rest = settled
                raise EngineError(
                    f"{self.name}: column of deck {deck} not at rest after {MAX_SETTLE_TSTAR:g} t* of settling "
                    f"behind the gate (kinetic energy {energy:.3g} J at step {steps}, at rest below {rest:.3g} J); "
                    "the gate was never removed"
                ) from exc
            raise

    def read(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Trajectory:
        """The collapse frames as a Trajectory; attrs add the contact law, E, k, the time step and
        the settle's steps and final kinetic energy."""
        work_dir = Path(work_dir)
        positions, radius = self.read_frames(case, packing, work_dir)
        settled = settle_record(work_dir / LOG)
        if settled is None:
            raise read_error(work_dir / LOG, "no 'settle:' line: these frames were not written by this deck")
        energy, settle_steps, _ = settled
        hertz = hertz_parameters(case)
        return self.grain_trajectory(
            case,
            positions,
            radius,
            contact_law="hertz" + (" + sjkr" if hertz.cohesion_energy_density > 0 else ""),
            youngs_modulus=hertz.youngs_modulus,
            poisson_ratio=hertz.poisson_ratio,
            cohesion_energy_density=hertz.cohesion_energy_density,
            dt=hertz.time_step,
            settle_steps=settle_steps,
            settled_kinetic_energy=energy,
            settled_height=float(np.max(positions[0, :, 1] + radius)),
        )
