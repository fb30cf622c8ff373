"""The builtin engine against known answers: restitution, sliding to rolling, energy, rest, runout."""

import json
import math

import numpy as np
import pytest

from dem.case import GRAVITY
from dem.collapse import simulate_collapse, state_from_packing
from dem.forces import ContactLaw
from dem.integrate import SimulationError, State, mechanical_energy, record, run, usable_threads
from dem.packing import blowup_box, settle_column, walls_open, walls_with_gate
from dem.runout import runout_curve
from tests.same_bits import run_in_fresh_processes, sha256_arrays

RADIUS = 212.5e-6
DENSITY = 2650.0
FREE = (0.0, 1.0, 0.0, math.inf)  # left, right, floor, no gate
BIG_BOX = (-1.0, 2.0, -1.0, 2.0)


def run_until_separated(state, law, dt, steps=4000):
    run(state, law, FREE, BIG_BOX, dt, steps, gravity=0.0)


# the default step (t_c / 50, MFIX's DTSOLID_FACTOR 50) and the coarser one a full-scale run may take
# (docs/experiments/time-step.md), with the restitution each gives to within: at t_c / 25 a damped contact's
# discrete impulse falls short by up to 3% (measured: 0.291 for e = 0.3)
STEPS = pytest.mark.parametrize("dt_over_contact_time", [1 / 50, 1 / 25])
E_TOLERANCE = {1 / 50: 0.02, 1 / 25: 0.04}


@STEPS
@pytest.mark.parametrize("restitution", [0.3, 0.6, 0.9])
def test_floor_rebound_speed_ratio_is_restitution(small_case, restitution, dt_over_contact_time):
    case = small_case.replace(restitution=restitution, size_scale=1.0, dt_over_contact_time=dt_over_contact_time)
    state = State.at_rest([[0.5, 1.5 * RADIUS]], [RADIUS], DENSITY)
    state.v[0, 1] = -0.5
    run_until_separated(state, ContactLaw.from_case(case), case.time_step)
    assert state.v[0, 1] / 0.5 == pytest.approx(restitution, rel=E_TOLERANCE[dt_over_contact_time])


@STEPS
@pytest.mark.parametrize("restitution", [0.3, 0.6, 0.9])
def test_head_on_pair_separates_at_restitution_times_approach(small_case, restitution, dt_over_contact_time):
    case = small_case.replace(restitution=restitution, size_scale=1.0, dt_over_contact_time=dt_over_contact_time)
    state = State.at_rest([[0.5, 0.5], [0.5 + 3 * RADIUS, 0.5]], [RADIUS, 1.1 * RADIUS], DENSITY)
    state.v[0, 0], state.v[1, 0] = 0.4, -0.6
    momentum = float(np.sum(state.mass * state.v[:, 0]))
    run_until_separated(state, ContactLaw.from_case(case), case.time_step)
    assert (state.v[1, 0] - state.v[0, 0]) / 1.0 == pytest.approx(restitution, rel=E_TOLERANCE[dt_over_contact_time])
    assert float(np.sum(state.mass * state.v[:, 0])) == pytest.approx(momentum, rel=1e-9, abs=1e-15)


@STEPS
def test_sliding_disc_ends_rolling_at_five_sevenths_after_predicted_time(small_case, dt_over_contact_time):
    """Sphere inertia: slip stops after 2 v0 / (7 mu g) at v = 5/7 v0."""
    mu, v0 = 0.4, 0.3
    case = small_case.replace(friction=mu, size_scale=1.0, dt_over_contact_time=dt_over_contact_time)
    state = State.at_rest([[0.05, RADIUS - 1e-12]], [RADIUS], DENSITY)
    state.v[0, 0] = v0
    law, dt = ContactLaw.from_case(case), case.time_step
    t_roll = 2 * v0 / (7 * mu * GRAVITY)
    chunk = 20
    times, slip, speed = [], [], []
    while state.steps * dt < 1.5 * t_roll:
        run(state, law, FREE, BIG_BOX, dt, chunk)
        times.append(state.steps * dt)
        slip.append(state.v[0, 0] + state.spin[0] * RADIUS)
        speed.append(state.v[0, 0])
    slip = np.abs(np.array(slip))
    t_stop = times[int(np.argmax(slip < 1e-3 * v0))]
    assert t_stop == pytest.approx(t_roll, rel=0.03)
    assert speed[-1] == pytest.approx(5 / 7 * v0, rel=0.03)


def test_energy_is_conserved_without_damping_or_friction(small_case):
    """e = 1, mu = 0: kinetic + potential + spring energy stays within 1% over a collapse."""
    packing = settle_column(small_case)
    elastic = small_case.replace(restitution=1.0, friction=0.0)
    state = state_from_packing(elastic, packing)
    law, walls = ContactLaw.from_case(elastic), walls_open(elastic)
    energy = [mechanical_energy(state, law, walls)]
    steps = math.ceil(0.25 * elastic.t_star / elastic.time_step)
    for _ in range(8):  # 2 t*: the column falls and spreads
        run(state, law, walls, blowup_box(elastic), elastic.time_step, steps)
        energy.append(mechanical_energy(state, law, walls))
    drop = energy[0] - min(float(np.min(state.x[:, 1])), 0.0)
    kinetic_peak = state.kinetic_energy()
    assert kinetic_peak > 0.01 * abs(energy[0])  # it really moved
    assert np.max(np.abs(np.array(energy) - energy[0])) < 0.01 * abs(energy[0]), drop


def test_settled_column_stays_at_rest_behind_gate(small_case):
    packing = settle_column(small_case)
    state = state_from_packing(small_case, packing)
    frames, _ = record(
        state,
        ContactLaw.from_case(small_case),
        walls_with_gate(small_case),
        blowup_box(small_case),
        small_case.time_step,
        small_case.t_star,
        3,
    )
    moved = np.linalg.norm(frames[-1] - frames[0], axis=1) / small_case.diameter
    # restarting from the stored packing resets the tangential springs: a few grains re-seat once,
    # the most a grain on the surface (0.01-0.05 d over seeds 3-5, and 0.14 d for seed 4 when the
    # settle stepped at t_c/50), never a slide of the column
    assert np.percentile(moved, 99) < 0.005 and np.mean(moved > 0.01) < 0.01 and moved.max() < 0.25
    # and then nothing flows: a lone rattler in a pore may still twitch
    late = np.linalg.norm(frames[2] - frames[1], axis=1) / small_case.diameter
    assert np.percentile(late, 99) < 0.001 and late.max() < 0.02
    assert packing.attrs["settled_height"] == pytest.approx(small_case.H_i, rel=0.25)


def test_runout_grows_monotonically_to_plateau_and_friction_shortens_it(small_case):
    finals = {}
    for mu in (0.3, 0.9):
        case = small_case.replace(friction=mu, duration_over_tstar=6.0, size_scale=2.0)
        t, runout = runout_curve(simulate_collapse(case), "connected_front")  # the instantaneous front
        finals[mu] = runout[-1]
        if mu == 0.9:
            # monotone up to the jitter of the 8 leading grains, then a plateau. (At mu = 0.3 the
            # front keeps creeping: discs roll freely on a smooth floor without rolling resistance.)
            assert np.all(np.maximum.accumulate(runout) - runout <= 0.10 * runout[-1])
            assert np.all(np.diff(runout[t <= 2.0]) > 0)  # the collapse itself is strictly monotone
            late = runout[t >= 5.0]
            assert np.ptp(late) < 0.10 * runout[-1]
    assert finals[0.3] > 1.1 * finals[0.9]


# one case in a fresh interpreter: the sha256 of its trajectory arrays
DEM_IN_A_PROCESS = (
    "import json, sys; from dem.case import CollapseCase; from dem.collapse import simulate_collapse; "
    "from tests.same_bits import sha256_arrays; "
    "t = simulate_collapse(CollapseCase.from_dict(json.loads(sys.argv[1]))); "
    "print(sha256_arrays(dict(positions=t.positions, radius=t.radius, particle_type=t.particle_type)))"
)


def test_same_seed_same_result_bit_for_bit(small_case):
    """The same case gives the same trajectory arrays, bit for bit: here and in two fresh interpreters
    with other hash seeds (no dict or set order, no state left from an earlier run)."""
    case = small_case.replace(duration_over_tstar=1.0)
    first = simulate_collapse(case)
    here = sha256_arrays(dict(positions=first.positions, radius=first.radius, particle_type=first.particle_type))
    assert run_in_fresh_processes(DEM_IN_A_PROCESS, [[json.dumps(case.to_dict())]] * 2, hash_seeds=(1, 2)) == [here] * 2
    other = simulate_collapse(case.replace(seed=4))
    assert not np.array_equal(first.positions[-1], other.positions[-1])


def test_same_bits_on_every_x86_64_target(small_case):
    """The kernels compiled for this processor and for a generic x86-64 (no AVX, no FMA: what an
    older or another machine may compile) give the same trajectory, bit for bit, on one thread and
    on two, with side-wall drag and rolling resistance on: the engine does IEEE arithmetic, so a
    case is the same run on any machine (dem/contact.py's FAST_MATH)."""
    case = small_case.replace(duration_over_tstar=0.5, sidewall_friction=0.3, rolling_friction=0.1)
    argv = [json.dumps(case.to_dict())]
    two_threads = DEM_IN_A_PROCESS.replace("json.loads(sys.argv[1])))", "json.loads(sys.argv[1])), threads=2)")
    assert two_threads != DEM_IN_A_PROCESS
    generic = {"NUMBA_CPU_NAME": "generic", "NUMBA_CPU_FEATURES": ""}
    for code in (DEM_IN_A_PROCESS, two_threads):
        host, other = run_in_fresh_processes(code, [argv, argv], env=[{}, generic])
        assert host == other


def test_two_threads_same_forces_and_same_bits(small_case, caplog):
    """dem.threads 2 splits the grains between threads: its steps follow the serial
    kernel's to rounding (a reaction across the split lost or counted twice would not), and a
    run gives the same bits every time. Side-wall drag and rolling resistance are on, so the
    sums the split reorders all matter."""
    case = small_case.replace(duration_over_tstar=1.0, sidewall_friction=0.3, rolling_friction=0.1)
    packing = settle_column(case)
    law, walls, box = ContactLaw.from_case(case), walls_open(case), blowup_box(case)
    serial, threaded, again = (state_from_packing(case, packing) for _ in range(3))
    steps = math.ceil(0.1 * case.t_star / case.time_step)  # the column starts to fall: every grain in contact
    run(serial, law, walls, box, case.time_step, steps)
    for state in (threaded, again):
        run(state, law, walls, box, case.time_step, steps, threads=2)
    moved = np.abs(serial.x - packing.positions[-1]).max()
    assert moved > 0.05 * case.diameter
    assert np.abs(threaded.x - serial.x).max() < 1e-9 * moved
    assert np.abs(threaded.spin - serial.spin).max() < 1e-9 * np.abs(serial.spin).max()
    assert np.array_equal(threaded.x, again.x) and np.array_equal(threaded.pairs[2], again.pairs[2])
    assert simulate_collapse(case.replace(duration_over_tstar=0.2), packing, threads=2).attrs["threads"] == 2
    with caplog.at_level("WARNING", logger="dem.integrate"):
        assert usable_threads(999) < 999
    assert "dem.threads: 999 asked" in caplog.text


class Killed(Exception):
    """The run killed midway, as by a SLURM time limit."""


def test_killed_run_resumes_from_its_checkpoint_with_the_same_bits(small_case, tmp_path, caplog):
    """A run killed midway goes on from its last checkpoint and ends with the bits of a run never
    stopped (full-scale runs take minutes); a checkpoint that does not read whole or is
    of another thread count is set aside, saying so, and the run starts clean."""
    case, threads = small_case.replace(duration_over_tstar=1.0), 2
    packing = settle_column(case)
    whole = simulate_collapse(case, packing, threads=threads)
    checkpoint = tmp_path / "checkpoint.npz"

    def kill_midway(fraction):
        if fraction > 0.5:
            raise Killed

    with pytest.raises(Killed):
        simulate_collapse(case, packing, kill_midway, threads, checkpoint=checkpoint, checkpoint_every_s=0.0)
    assert checkpoint.exists()
    kept = checkpoint.read_bytes()
    resumed = simulate_collapse(case, packing, threads=threads, checkpoint=checkpoint)
    assert case.n_frames // 2 <= resumed.attrs["resumed_from_frame"] < case.n_frames
    assert np.array_equal(resumed.positions, whole.positions)
    assert resumed.attrs["steps"] == whole.attrs["steps"] and not checkpoint.exists()

    for why, bad in (("BadZipFile", kept[: len(kept) // 2]), ("another case", None)):
        if bad is None:  # the same checkpoint, but the run asks for another thread count
            checkpoint.write_bytes(kept)
            threads = 3 - threads
            whole = simulate_collapse(case, packing, threads=threads)
        else:
            checkpoint.write_bytes(bad)
        caplog.clear()
        with caplog.at_level("WARNING", logger="dem.collapse"):
            clean = simulate_collapse(case, packing, threads=threads, checkpoint=checkpoint)
        assert f"checkpoint {checkpoint} set aside, starting clean" in caplog.text and why in caplog.text
        assert clean.attrs["resumed_from_frame"] == 0 and np.array_equal(clean.positions, whole.positions)


def test_blow_up_is_reported_with_case_and_step(small_case):
    state = State.at_rest([[0.5, 0.5], [0.5 + RADIUS, 0.5]], [RADIUS, RADIUS], DENSITY)  # 50% overlap
    with pytest.raises(SimulationError, match=r"case small.*step 0.*overlap"):
        run(state, ContactLaw.from_case(small_case), FREE, BIG_BOX, 1e-7, 10, label="case small")
    state = State.at_rest([[0.5, 0.5]], [RADIUS], DENSITY)
    state.v[0, 0] = np.nan
    with pytest.raises(SimulationError, match="non-finite"):
        run(state, ContactLaw.from_case(small_case), FREE, BIG_BOX, 1e-7, 10)
    state = State.at_rest([[0.5, 0.5]], [RADIUS], DENSITY)
    state.v[0, 1] = 1e3
    with pytest.raises(SimulationError, match="left the box"):
        run(state, ContactLaw.from_case(small_case), FREE, (0, 1, 0, 1), 1e-5, 1000, gravity=0.0)
