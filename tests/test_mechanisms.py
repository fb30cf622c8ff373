"""The candidate mechanisms beyond the paper's model, each against a known answer."""

import math

import pytest
from scipy.optimize import minimize_scalar

from calibration.mechanisms import get_mechanisms, plausible_for
from calibration.model import Model
from dem.case import GRAVITY, CollapseCase
from dem.collapse import simulate_collapse
from dem.engines.liggghts_hertz import MAX_OVERLAP, hertz_parameters, sjkr_energy_density, sjkr_pull_off_force
from dem.forces import ContactLaw
from dem.integrate import State, run
from pipeline.contenders_section import plausibility_lines

RADIUS = 212.5e-6
DENSITY = 2650.0
FLOOR_ONLY = (-1.0, 2.0, 0.0, math.inf)
BIG_BOX = (-2.0, 3.0, -1.0, 2.0)
COHESION = next(m for m in get_mechanisms() if m.name == "cohesion")


def case_with(**changes):
    return CollapseCase("quartz", 0.02, 1.0, friction=0.5, restitution=0.5, **changes)


def grain_on_floor():
    """A grain resting on the floor with its weight on the spring."""
    mass = DENSITY * math.pi * (2 * RADIUS) ** 3 / 6
    return State.at_rest([[0.1, RADIUS - mass * GRAVITY / 1000.0]], [RADIUS], DENSITY)


def travel_until_stopped(state, law, dt, max_time, chunk=50):
    x0 = state.x[0, 0]
    while state.time < max_time:
        run(state, law, FLOOR_ONLY, BIG_BOX, dt, chunk)
        if abs(state.v[0, 0]) < 1e-4 and state.time > 1e-3:
            break
    return state.x[0, 0] - x0, state.time


def test_rolling_resistance_stops_a_rolling_disc_at_predicted_distance():
    """EPSD2 torque mu_r r m g on a disc rolling without slip: a = 5/7 mu_r g,
    distance 7 v0^2 / (10 mu_r g)."""
    mu_r, v0 = 0.1, 0.2
    case = case_with(rolling_friction=mu_r)
    state = grain_on_floor()
    state.v[0, 0], state.spin[0] = v0, -v0 / RADIUS
    distance, _ = travel_until_stopped(state, ContactLaw.from_case(case), case.time_step, 1.0)
    assert distance == pytest.approx(7 * v0**2 / (10 * mu_r * GRAVITY), rel=0.03)
    # and without it the disc rolls on
    free = grain_on_floor()
    free.v[0, 0], free.spin[0] = v0, -v0 / RADIUS
    run(free, ContactLaw.from_case(case_with()), FLOOR_ONLY, BIG_BOX, case.time_step, 20000)
    assert free.v[0, 0] == pytest.approx(v0, rel=1e-3)


@pytest.mark.parametrize("pull_over_pull_off, separates", [(0.9, False), (1.1, True)])
def test_cohesive_grain_leaves_the_floor_only_above_jkr_pull_off(pull_over_pull_off, separates):
    """Pull-off force 1.5 pi w R* (R* = r on a wall): a weaker pull holds, a stronger one lifts."""
    w = 0.05  # J/m^2
    case = case_with(cohesion_energy=w)
    state = grain_on_floor()
    pull_off = 1.5 * math.pi * w * RADIUS
    pull_acceleration = pull_over_pull_off * pull_off / state.mass[0]
    # "gravity" pointing up: a pull of pull_acceleration * m away from the floor
    run(state, ContactLaw.from_case(case), FLOOR_ONLY, BIG_BOX, case.time_step, 20000, gravity=-pull_acceleration)
    lifted = state.x[0, 1] > 2 * RADIUS
    assert lifted == separates


def test_sidewall_friction_stops_a_sliding_grain_at_predicted_distance():
    """Channel side walls: drag mu_sw (d / W) |Fn| against the motion; on a frictionless floor a
    grain sliding at v0 stops after v0^2 / (2 mu_sw (d / W) g)."""
    mu_sw, width, v0 = 0.5, 0.004, 0.1
    case = case_with(friction_base=0.0, sidewall_friction=mu_sw, channel_width=width)
    state = grain_on_floor()
    state.v[0, 0] = v0
    distance, _ = travel_until_stopped(state, ContactLaw.from_case(case), case.time_step, 1.0)
    deceleration = mu_sw * (2 * RADIUS / width) * GRAVITY
    assert distance == pytest.approx(v0**2 / (2 * deceleration), rel=0.03)


def test_basal_friction_is_the_floor_friction_alone():
    """A sliding disc turns to rolling after 2 v0 / (7 mu_base g), whatever the other walls' mu."""
    mu_base, v0 = 0.2, 0.3
    case = case_with(friction_wall=0.8, friction_base=mu_base)
    state = grain_on_floor()
    state.v[0, 0] = v0
    law, dt = ContactLaw.from_case(case), case.time_step
    while abs(state.v[0, 0] + state.spin[0] * RADIUS) > 1e-3 * v0:
        run(state, law, FLOOR_ONLY, BIG_BOX, dt, 10)
    assert state.time == pytest.approx(2 * v0 / (7 * mu_base * GRAVITY), rel=0.03)


def test_lifting_gate_lets_grains_out_from_below_only():
    speed = 0.2  # m/s: the gate clears the 20 mm column in 0.1 s, about 2 t*
    base = CollapseCase("quartz", 0.02, 1.0, 0.5, 0.65, size_scale=3.0, seed=1, duration_over_tstar=2.0)
    lifted = simulate_collapse(base.replace(gate_lift_speed=speed))
    L_i = base.L_i
    for k, t in enumerate(lifted.times):
        out = lifted.positions[k, :, 0] > L_i + lifted.radius
        if out.any():  # they passed under the gate's lower edge and can only have fallen since
            assert lifted.positions[k, out, 1].max() <= speed * t + 2 * lifted.radius.max()
    instant = simulate_collapse(base)
    assert lifted.positions[-1, :, 0].max() < instant.positions[-1, :, 0].max()


def test_sjkr_pull_off_force_is_the_minimum_of_hertz_plus_sjkr():
    """The Hertz + SJKR pull-off force (closed form) against the numerical minimum of
    F(delta) = 4/3 E* sqrt(R*) delta^1.5 - k A(delta), with A = 2 pi R* delta; a case's cohesion (a
    Bond number) becomes the k whose pull-off force of a mean pair is that many mean-grain weights,
    within 1% also with the exact sphere-sphere intersection area SJKR uses, resting within
    MAX_OVERLAP of d."""

    def pull_off(e_star, r_eff, k, area):  # the numerical minimum, as a pulled pair feels it
        hertz = lambda delta: 4 / 3 * e_star * math.sqrt(r_eff) * delta**1.5  # noqa: E731
        found = minimize_scalar(
            lambda delta: hertz(delta) - k * area(delta),
            bounds=(0.0, 0.1 * r_eff),
            method="bounded",
            options={"xatol": 1e-15},
        )
        return -found.fun, found.x

    e_star, r_eff, k = 2.0e6, 5.3e-4, 2.0e5
    force, overlap = pull_off(e_star, r_eff, k, lambda delta: 2 * math.pi * r_eff * delta)
    assert force == pytest.approx(sjkr_pull_off_force(k, e_star, r_eff), rel=1e-9)
    assert overlap == pytest.approx(math.pi**2 * k**2 * r_eff / e_star**2, rel=1e-4)
    assert sjkr_energy_density(force, e_star, r_eff) == pytest.approx(k, rel=1e-9)
    # Bond number 30 through the cohesion candidate and the deck's parameters
    case = Model(COHESION).at(CollapseCase("quartz", 0.02, 2.0, 0.5, 0.6, size_scale=5), [0.5, 0.6, 30])
    params = hertz_parameters(case)
    weight = case.sphere_mass(case.diameter) * 9.81
    r_eff, radius = case.diameter / 4, case.diameter / 2  # a mean pair

    def lens_area(delta):  # SJKR's area (LIGGGHTS cohesion_model_sjkr.h), equal spheres 2 R - delta apart
        dist = 2 * radius - delta
        return -math.pi / 4 * (dist - 2 * radius) * dist * dist * (dist + 2 * radius) / dist**2

    k, e_star = params.cohesion_energy_density, params.effective_modulus
    assert sjkr_pull_off_force(k, e_star, r_eff) == pytest.approx(30 * weight, rel=1e-9)
    assert pull_off(e_star, r_eff, k, lens_area)[0] == pytest.approx(30 * weight, rel=0.01)
    resting = 9 / 4 * math.pi**2 * k**2 * r_eff / e_star**2  # where Hertz balances SJKR
    assert resting == pytest.approx(MAX_OVERLAP * case.diameter, rel=1e-9)  # the load that sets E here


def test_each_mechanism_states_its_physical_range_and_a_fit_outside_it_is_called_effective():
    """Every candidate states the range its parameter takes for dry grains, with a source; the
    report calls the answer's value outside it effective, and says nothing of friction and
    restitution, which the paper's box already bounds."""
    for mechanism in get_mechanisms():
        low, high = mechanism.plausible
        assert math.isfinite(low) and math.isfinite(high) and low < high and mechanism.plausible_source
        assert "effective" not in mechanism.plausibility((low + high) / 2)
        assert mechanism.plausibility(2 * high + 1).endswith("an effective parameter, not a physical one")
    # the shipped answers' Bond numbers of 41-56 for dry sand: effective
    (line, _) = plausibility_lines({"friction": 0.715, "restitution": 0.9, "bond_number": 55.6})
    assert line.startswith("**Plausibility.** bond_number = 55.6 lies outside the physical range [0, 1]")
    assert "Castellanos 2005" in line and "friction =" not in line
    assert plausibility_lines({"friction": 0.5, "restitution": 0.6}) == []


def test_a_material_states_its_own_plausible_ranges_or_is_told_it_takes_the_defaults():
    """calibration.plausible_ranges: a stated range and source replace the built-in one for that
    material; the table's quartz and copper keep the built-in ones as they are; a material of the
    user's own that states none takes them, and its plausibility says so; the report's sentence
    follows the range calibrated.json carries."""
    wall = get_mechanisms(["sidewall_friction"])[0]
    stated = {"glass_beads": {"sidewall_friction": {"range": [0.05, 0.15], "source": "our tilting-plane tests"}}}
    own = plausible_for(wall, "glass_beads", stated)
    assert own.plausible == (0.05, 0.15) and own.bounds == wall.bounds and own.channel_width == wall.channel_width
    assert own.plausibility(0.2).endswith("(our tilting-plane tests): an effective parameter, not a physical one")
    assert "effective" not in wall.plausibility(0.2)  # the built-in [0.1, 0.6] calls it physical
    assert plausible_for(wall, "quartz", stated) == wall
    default = plausible_for(wall, "basalt", stated)
    assert default.plausible == wall.plausible
    assert "the default for dry grains of 0.1-1 mm, as 'basalt' states none" in default.plausibility(0.2)
    plausible = [{"parameter": "sidewall_friction", "range": [0.05, 0.15], "source": "our tilting-plane tests"}]
    (line, _) = plausibility_lines({"friction": 0.4, "restitution": 0.6, "sidewall_friction": 0.2}, plausible)
    assert "outside the physical range [0.05, 0.15] (our tilting-plane tests)" in line
