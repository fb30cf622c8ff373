"""The discrepancy diagnosis' rules, without DEM: the candidate registry, the emulator and its fits,
residuals said in plain words, the runs test and held-out folds, the predictive check, the decision
rule, bad input, the library's file and the profile read as
stated (its noise, its weight against the runout). The hidden-mechanism checks
on real DEM runs are tests/test_diagnosis.py's."""

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from calibration.decision import DecisionRule, decide, unsettled
from calibration.design_runs import DesignRuns, Library
from calibration.diagnosis import mechanism_on
from calibration.emulator import GPEmulator, ParameterBox, latin_hypercube
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import MechanismError, bond_from_cohesion_energy, cohesion_energy_from_bond, get_mechanisms
from calibration.model import Model
from calibration.observables import Observables
from calibration.residuals import DiagnosisError, check_data, held_out_folds, noise_model, residual_structure, runs_test
from calibration.scoring import box_bounded_covariance, fit_emulated, predictive_chi2
from calibration.synthetic import (
    evidence_margins,
    synthetic_columns,
)
from calibration.uncertainty import laplace_posterior
from dem.case import CollapseCase
from dem.runout import RunoutMethod, runout_curve
from dem.trajectory import Trajectory

MECHANISMS = {m.name: m for m in get_mechanisms()}


# -- candidate registry --------------------------------------------------------------------------------------
def test_candidates_map_to_engine_fields():
    case = CollapseCase("quartz", 0.02, 1.0, 0.5, 0.6, size_scale=4)
    w = MECHANISMS["cohesion"].case_fields(30.0, case)["cohesion_energy"]
    assert w == pytest.approx(cohesion_energy_from_bond(30.0, case))
    assert bond_from_cohesion_energy(w, case) == pytest.approx(30.0)
    # Bond number: pull-off 1.5 pi w d/4 over a mean grain's weight
    weight = case.sphere_mass(case.diameter) * 9.81
    assert 1.5 * math.pi * w * case.diameter / 4 / weight == pytest.approx(30.0, rel=1e-6)
    assert MECHANISMS["gate_lift"].case_fields(2.0, case) == {"gate_lift_speed": 0.5}
    assert MECHANISMS["gate_lift"].case_fields(0.0, case) == {"gate_lift_speed": 0.0}
    assert MECHANISMS["sidewall_friction"].case_fields(0.1, case) == {"sidewall_friction": 0.1, "channel_width": 0.01}
    assert MECHANISMS["rolling_resistance"].case_fields(0.2, case) == {"rolling_friction": 0.2}
    assert MECHANISMS["basal_friction"].off_value(0.45, 0.6) == 0.45  # the base model's floor
    assert MECHANISMS["rolling_resistance"].off_value(0.45, 0.6) == 0.0
    with pytest.raises(MechanismError, match="rolling_friction = 0.9 outside"):
        MECHANISMS["rolling_resistance"].case_fields(0.9, case)
    with pytest.raises(MechanismError, match="unknown candidate mechanism"):
        get_mechanisms(["rolling_resistance", "magnetism"])
    for m in MECHANISMS.values():  # the hidden magnitudes lie inside the searched box, away from "off"
        assert m.bounds[0] <= m.hidden_range[0] < m.hidden_range[1] <= m.bounds[1]


def test_parameter_box_log_scale():
    box = Model(MECHANISMS["basal_friction"]).box
    theta = np.array([[0.5, 0.6, 0.02], [0.3, 0.9, 1.0], [0.9, 0.3, math.sqrt(0.02)]])
    unit = box.to_unit(theta)
    assert unit[:, 2] == pytest.approx([0.0, 1.0, 0.5])  # geometric middle of [0.02, 1]
    assert box.from_unit(unit) == pytest.approx(theta)
    design = latin_hypercube(box, 8, seed=1)
    assert np.all(design >= box.bounds[:, 0]) and np.all(design <= box.bounds[:, 1])
    assert np.sort(box.to_unit(design)[:, 2] * 8).astype(int).tolist() == list(range(8))  # one per stratum


def test_runout_front_never_moves_back():
    """A block of leading grains that comes to rest more than 2 d ahead of the rest drops out of
    dem.runout's connected deposit; the "_reached" runout (the diagnosis' before the runout
    contract, still available to it) keeps the farthest front reached."""
    radius = np.full(20, 1e-3)
    row = np.column_stack([1e-3 + 2e-3 * np.arange(20), radius])  # 20 touching grains on the floor
    split = row.copy()
    split[10:, 0] += 10e-3  # the leading 10 grains 5 d ahead
    grown = row.copy()
    grown[:, 0] *= 1.5  # gaps of 1 mm (< 2 d): still one deposit
    positions = np.stack([row, grown, split, split]).astype(np.float32)
    trajectory = Trajectory(positions, radius, np.zeros(20, np.int32), {"L_i": 0.01, "dt_frame": 0.01, "t_star": 0.1})
    t, raw = runout_curve(trajectory, "connected_front")
    t_front, front = RunoutMethod("connected_front_reached").curve(trajectory)
    assert np.array_equal(t, t_front)
    assert raw[2] < raw[1] - 2.0  # the connected front jumps back
    assert front[:2] == pytest.approx(raw[:2]) and front[1] > front[0]  # a growing front is read as is
    assert front[2] == front[3] == pytest.approx(raw[1])  # ... and never moves back


# -- emulator and fits -------------------------------------------------------------------------------------
def response(theta):
    """A smooth nonlinear two-output function of (x, y) in [0, 1]^2, one-to-one (Jacobian
    determinant -1 - 2 y e^x < 0 everywhere)."""
    x, y = theta[:, 0], theta[:, 1]
    return np.column_stack([x + y**2, np.exp(x) - y])


def test_emulator_reproduces_a_known_function_and_its_noise():
    box = ParameterBox(np.array([[0.0, 1.0], [0.0, 1.0]]), (False, False))
    rng = np.random.default_rng(0)
    design = latin_hypercube(box, 30, seed=2)
    noise = 0.02
    emulator = GPEmulator(box, seed=0).fit(design, response(design) + rng.normal(0, noise, (30, 2)))
    test = latin_hypercube(box, 50, seed=3)
    error = emulator.predict(test) - response(test)
    assert np.sqrt(np.mean(error**2)) < 3 * noise
    # leave-one-out error: the noise itself, plus a little emulation error
    assert np.all(emulator.loo_rmse() > 0.5 * noise) and np.all(emulator.loo_rmse() < 4 * noise)
    truth = np.array([0.3, 0.7])
    target = response(truth[None])[0]
    found, chi2 = fit_emulated(emulator, target, np.full(2, noise))
    assert found == pytest.approx(truth, abs=0.06)
    assert chi2 < 4.0


# -- plain words, runs test, held-out folds ----------------------------------------------------------------
def two_columns(profile=True):
    t = np.array([0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0])
    columns = []
    for a in (1.0, 2.0):
        x = np.array([0.005, 0.015, 0.03]) if profile else None
        columns.append(
            MeasuredColumn(
                f"q{a:g}",
                "quartz",
                a,
                0.02,
                t,
                a * np.sqrt(t),
                np.full(len(t), 0.05),
                x,
                None if x is None else np.array([0.02, 0.015, 0.005]),
                "memory",
            )
        )
    return columns


def test_residuals_said_in_plain_words():
    observables = Observables(two_columns())
    measured = observables.measured
    kind, x, column = observables.kind, observables.x, observables.column_index
    predicted = measured.copy()
    late = (kind == "runout") & (x > 2.5)
    predicted[late] += np.where(column[late] == 0, 0.3, 0.6)  # overshoot, larger for a = 2
    near_wall = (kind == "profile") & (x <= 0.02)
    predicted[near_wall] -= 0.004  # deposit too low at the wall
    sigma = np.where(kind == "runout", 0.05, 0.001)
    words = residual_structure(observables, predicted, sigma, 2)
    summary = words.summary
    assert "beyond the stated noise" in summary
    assert (
        "In the stopping phase the simulated runout overshoots in every column, more for taller columns "
        "(a = 1: +0.30 L*, a = 2: +0.60 L*)"
    ) in summary
    assert "deposit behind the gate (x <= L_i) the simulated deposit is lower than measured in every column" in summary
    assert "free-fall" not in summary and "spreading" not in summary
    stopping = [g for g in words.groups if g.group.startswith("stopping")]
    assert all(g.biased for g in stopping)
    clean = residual_structure(observables, measured + 0.01 * np.sin(np.arange(len(measured))) * sigma, sigma, 2)
    assert "within the stated noise" in clean.summary and "overshoots" not in clean.summary


def test_runs_test():
    assert runs_test([1, 1, 1, 1, 1, 1]) == pytest.approx(2.0**-5)
    assert runs_test([1, -1, 1, -1, 1, -1, 1, -1]) > 0.9  # alternating: no structure
    assert runs_test([-1, -1, -1, -1, 1, 1, 1, 1]) < 0.05  # two long runs: structure


def test_held_out_folds():
    two = Observables(two_columns())
    folds = held_out_folds(two)
    assert [f.columns for f in folds] == [(0,), (1,)]
    assert np.array_equal(folds[0].held, two.column_index == 0)
    one = Observables(two_columns()[:1])
    phases = held_out_folds(one)
    assert len(phases) == 3 and all(not f.held[one.kind == "profile"].any() for f in phases)
    assert np.sum([f.held for f in phases], axis=0)[one.kind == "runout"].tolist() == [1] * 8


# -- the held-out score: a predictive check ------------------------------------------------------------
def test_heldout_chi2_carries_the_fold_fits_parameter_uncertainty():
    """A linear model y = J theta, theta in [0, 1]^2, noise 1. The fold's fit sees only theta_0 (16
    values, J = [1, 0]); the held-out value moves with both (J = [1, 3]) and is missed by 2. By hand:
    theta_0's Laplace variance 1/16 bounded by the box's 1/12 -> 1/(16 + 12) = 1/28; theta_1 unseen
    -> the box's variance 1/12; chi^2 = 2^2 / (1 + 1/28 + 9/12), below the plug-in 4."""
    bounds = np.array([[0.0, 1.0], [0.0, 1.0]])
    fit_jacobian = np.tile([1.0, 0.0], (16, 1))
    posterior = laplace_posterior(["a", "b"], [0.5, 0.5], fit_jacobian, np.zeros(16), bounds.tolist(), sigma=1.0)
    assert posterior.parameters[0].identifiable and not posterior.parameters[1].identifiable
    covariance = box_bounded_covariance(posterior.covariance, bounds)
    np.testing.assert_allclose(covariance, np.diag([1 / 28, 1 / 12]), rtol=1e-9, atol=1e-12)
    held = np.array([[1.0, 3.0]])
    assert predictive_chi2([2.0], [1.0], held, covariance) == pytest.approx(4 / (1 + 1 / 28 + 9 / 12), rel=1e-9)
    assert predictive_chi2([2.0], [1.0]) == 4.0  # plug-in: no parameter uncertainty
    # a miss the parameters cannot move (J = 0 on that value) costs what it did
    assert predictive_chi2([2.0, 1.0], [1.0, 0.5], np.array([[1.0, 3.0], [0.0, 0.0]]), covariance) == pytest.approx(
        4 / (1 + 1 / 28 + 9 / 12) + 4.0
    )
    # several values: r^T (diag(sigma^2) + J Sigma J^T)^-1 r, in any units (sigma and r in mm here)
    jacobian, sigma, residual = np.array([[1.0, 3.0], [2.0, -1.0], [0.5, 0.5]]), np.array([1.0, 2.0, 0.5]), np.ones(3)
    total = np.diag(sigma**2) + jacobian @ covariance @ jacobian.T
    expected = residual @ np.linalg.solve(total, residual)
    assert predictive_chi2(residual, sigma, jacobian, covariance) == pytest.approx(expected, rel=1e-9)
    # the box bounds every variance, whatever the Laplace covariance; a well-determined one is kept
    wide = box_bounded_covariance(np.diag([1e30, 1e-8]), np.array([[0.0, 60.0], [0.3, 0.9]]))
    assert wide[0, 0] == pytest.approx(60.0**2 / 12) and wide[1, 1] == pytest.approx(1e-8, rel=1e-5)


# -- the decision rule ---------------------------------------------------------------------------------
def dem_entry(chi2, heldout, n=20, p=3, p_value=None):
    """The part of a DEMScore the decision reads."""
    return SimpleNamespace(
        chi2=chi2,
        bic=chi2 + p * math.log(n),
        heldout_chi2=heldout,
        n_heldout=n,
        p_value=(0.5 if chi2 < n else 1e-6) if p_value is None else p_value,
    )


def test_decision_names_a_cause_only_when_decisive():
    rule = DecisionRule()
    decisive = {
        "base": dem_entry(120, 130, p=2),
        "cohesion": dem_entry(22, 30),
        "rolling_resistance": dem_entry(60, 80),
    }
    cause, checks, verdict = decide(decisive, rule, [], "cohesion")
    assert cause == "cohesion" and all(checks.values()) and verdict.startswith("Cause: cohesion")
    close = dict(decisive, rolling_resistance=dem_entry(25, 35))  # runner-up 3 behind
    cause, checks, _ = decide(close, rule, [], "cohesion")
    assert cause == "none" and not checks["bic_beats_runner_up"]
    worse_heldout = dict(decisive, cohesion=dem_entry(22, 110))  # held-out gain 15% only
    assert decide(worse_heldout, rule, [], "cohesion")[0] == "none"
    # held out no better than the runner-up: a tie (within sqrt(2 n) = 6.3 of a chi^2 over 20
    # held-out values) leaves the BIC margin to decide; clearly worse out of sample is overfitting
    tie = dict(decisive, cohesion=dem_entry(22, 84))
    assert decide(tie, rule, [], "cohesion")[0] == "cohesion"
    overfit = dict(decisive, cohesion=dem_entry(22, 87), rolling_resistance=dem_entry(60, 80, p_value=0.05))
    cause, checks, _ = decide(overfit, rule, [], "cohesion")
    assert cause == "none" and not checks["heldout_no_worse_than_runner_up"]
    assert decide(decisive, rule, ["runout looks like metres"], "cohesion")[0] == "none"
    assert decide(decisive, rule, [], "rolling_resistance")[0] == "none"  # emulator disagrees
    nothing = {"base": dem_entry(18, 20, p=2), "cohesion": dem_entry(17, 22), "gate_lift": dem_entry(18, 25)}
    cause, _, verdict = decide(nothing, rule, [], "cohesion")
    assert cause == "none" and "no candidate improves" in verdict
    # a decisive fit with its mechanism off is the base model at another (mu, e): never a cause
    cause, checks, verdict = decide(decisive, rule, [], "cohesion", {"cohesion": False, "rolling_resistance": True})
    assert cause == "none" and not checks["mechanism_on"] and "mechanism_on" in verdict
    assert decide(decisive, rule, [], "cohesion", {"cohesion": True})[0] == "cohesion"
    # another DEM round only where a candidate beats the base model by the BIC margin and yet no
    # cause is named: not for a cause, nor where nothing beats the base model or the data warned
    assert unsettled(*decide(close, rule, [], "cohesion")[:2]) and unsettled(*decide(overfit, rule, [], "cohesion")[:2])
    assert not unsettled(*decide(decisive, rule, [], "cohesion")[:2])
    assert not unsettled(*decide(nothing, rule, [], "cohesion")[:2])
    assert not unsettled(*decide(decisive, rule, ["runout looks like metres"], "cohesion")[:2])


def test_a_mechanism_at_its_off_value_is_off():
    """The LIGGGHTS case that named gate lift at gate slowness 0 (basal friction 0.23;
    docs/experiments/diagnosis.md): each candidate's off value, the basal friction's being the fitted mu."""
    models = {m.name: Model(m) for m in get_mechanisms()}
    fit = {"friction": 0.48, "restitution": 0.75}
    assert not mechanism_on(models["gate_lift"], dict(fit, gate_slowness=0.0))
    assert mechanism_on(models["gate_lift"], dict(fit, gate_slowness=0.2))  # 5% of its range
    assert not mechanism_on(models["basal_friction"], dict(fit, friction_base=0.48 + 0.005))
    assert mechanism_on(models["basal_friction"], dict(fit, friction_base=0.555))
    assert not mechanism_on(models["cohesion"], dict(fit, bond_number=0.0))
    assert not mechanism_on(Model(), fit)


def test_benchmark_margins_never_mix_dem_and_emulator_bic():
    """A candidate scored only on its emulator is compared with the emulator's base fit, never the DEM's."""

    def evidence(dem_bic, dem_heldout, final_bic):  # the part of an Evidence the margins read
        return SimpleNamespace(
            dem=None if dem_bic is None else SimpleNamespace(bic=dem_bic, heldout_chi2=dem_heldout),
            emulator_final=SimpleNamespace(bic=final_bic),
        )

    result = SimpleNamespace(
        base=evidence(100.0, 80.0, 150.0),
        candidates={
            "cohesion": evidence(30.0, 20.0, 40.0),
            "gate_lift": evidence(45.0, 30.0, 50.0),
            "basal_friction": evidence(None, None, 35.0),
        },
    )
    margins = evidence_margins(result)
    assert margins["delta_bic_dem"] == {"cohesion": 70.0, "gate_lift": 55.0}
    assert margins["delta_bic_emulator"] == {"cohesion": 110.0, "gate_lift": 100.0, "basal_friction": 115.0}
    assert margins["margins"] == {
        "dem_best": "cohesion",
        "bic_vs_base": 70.0,
        "bic_vs_runner_up": 15.0,
        "heldout_gain": 0.75,
    }


def test_candidates_figure_has_numeric_ticks_and_the_rules_thresholds():
    """The thresholds are drawn where the rule applies them (DEM runs: ΔBIC vs base and vs the
    runner-up, held-out chi^2 vs the base model's and the runner-up's), and every axis has numbers."""
    import matplotlib.pyplot as plt

    from calibration.diagnosis_report import candidates_figure

    rule = DecisionRule()
    dem = {"base": dem_entry(120, 130, p=2), "cohesion": dem_entry(22, 30), "rolling_resistance": dem_entry(25, 35)}
    cause, checks, _ = decide(dem, rule, [], "cohesion")  # runner-up only 3 behind: no cause

    def evidence(name, emulator_bic, emulator_heldout):  # the part of an Evidence the figure reads
        return SimpleNamespace(
            model=name,
            emulator=SimpleNamespace(bic=emulator_bic, heldout_chi2=emulator_heldout),
            dem=dem.get(name),
        )

    result = SimpleNamespace(
        name="test",
        cause=cause,
        checks=checks,
        decision_rule=rule,
        best_candidate="cohesion",
        base=evidence("base", 150.0, 160.0),
        candidates={
            n: evidence(n, b, h)
            for n, b, h in [("cohesion", 40.0, 35.0), ("rolling_resistance", 45.0, 50.0), ("gate_lift", 90.0, 100.0)]
        },
    )
    fig = candidates_figure(result)
    try:
        fig.canvas.draw()
        bic_ax, heldout_ax = fig.axes[:2]
        for ax in (bic_ax, heldout_ax):
            numbers = [float(t.get_text().replace("−", "-")) for t in ax.get_xticklabels() if t.get_text()]
            assert len(numbers) >= 3 and ax.get_xlabel()

        def lines_at(ax):
            return {round(float(line.get_xdata()[0]), 6) for line in ax.get_lines() if len(set(line.get_xdata())) == 1}

        base, best, runner_up = dem["base"], dem["cohesion"], dem["rolling_resistance"]
        assert round(rule.min_delta_bic_vs_base, 6) in lines_at(bic_ax)
        assert round(base.bic - runner_up.bic + rule.min_delta_bic_vs_runner_up, 6) in lines_at(bic_ax)
        assert round((1 - rule.min_heldout_gain) * base.heldout_chi2, 6) in lines_at(heldout_ax)
        tie = rule.heldout_tie_sd * math.sqrt(2 * best.n_heldout)
        assert round(runner_up.heldout_chi2 + tie, 6) in lines_at(heldout_ax)
        legend = " ".join(t.get_text() for t in bic_ax.get_legend().get_texts())
        assert "≥ 10 to name a cause" in legend and "FAILED" in legend  # bic_beats_runner_up failed
    finally:
        plt.close(fig)


# -- bad input (a small library of real arrays, no DEM) ------------------------------------------------
def small_library(observables, scale=1.0):
    """Design runs of the base model only: the measured values times (1.5 - friction), 3 replicates."""
    rng = np.random.default_rng(0)
    box = Model().box
    theta = np.vstack([latin_hypercube(box, 6, 0), np.tile(box.centre, (3, 1))])
    base = np.concatenate(
        [c.runout if c.profile_x is None else np.concatenate([c.runout, c.profile_height]) for c in observables.columns]
    )
    observed = np.array([base * (1.5 - th[0]) * scale for th in theta]) + rng.normal(0, 0.01, (9, len(base)))
    runs = DesignRuns(
        "base", theta, observed, np.arange(9) % 3, np.ones(9), np.array(["design"] * 6 + ["replicate"] * 3)
    )
    return Library(observables.signature(), {"size_scale": 4.0}, {"base": runs})


def test_bad_input_is_an_error_not_a_cause():
    columns = two_columns(profile=False)
    observables = Observables(columns)
    library = small_library(observables)
    noise, notes = noise_model(observables, library)
    assert notes == [] and np.all(noise.total >= 0.05)
    models = [Model()]
    # runout given in metres (L - L_i = L* x 0.02 m): far below everything the simulator produced
    metres = [replace(c, runout=c.runout * c.L_i) for c in columns]
    with pytest.raises(DiagnosisError, match="metres"):
        check_data(Observables(metres), library, models, noise)
    # ... but units belong to the file: one short column that barely moved beside one that collapsed is data
    mixed = [replace(columns[0], runout=columns[0].runout * columns[0].L_i), columns[1]]
    assert any("barely moved" in note for note in check_data(Observables(mixed), library, models, noise))
    # runout in per cent (100 L*): far above every run; a little above the farthest run is data (a
    # model's box can reach beyond its few design runs)
    per_cent = [replace(c, runout=c.runout * 100) for c in columns]
    with pytest.raises(DiagnosisError, match="check the units"):
        check_data(Observables(per_cent), library, models, noise)
    highest = library.runs["base"].observed.max()
    beyond = [replace(c, runout=c.runout * 1.2 * highest / c.runout.max()) for c in columns]
    assert any("outside the range" in note for note in check_data(Observables(beyond), library, models, noise))
    # ... and so is a column that stands (L* small but flat, say cohesive grains)
    standing = [replace(c, runout=np.full(len(c.runout), 0.02)) for c in columns]
    assert check_data(Observables(standing), library, models, noise)  # only a note: out of the runs' range
    # ... also when every column of the file stands and its points scatter by their stated noise, which
    # spans more than half their peak (LIGGGHTS' cohesive columns, benchmarks/diagnosis_liggghts.py)
    noisy = np.random.default_rng(3).normal(0.0, 0.05, (2, len(columns[0].runout)))
    standing = [replace(c, runout=np.abs(n)) for c, n in zip(columns, noisy)]
    assert check_data(Observables(standing), library, models, noise)
    # a single time point (or two) is no curve
    short = [
        replace(
            columns[0],
            t_over_tstar=np.array([1.0, 2.0]),
            runout=np.array([1.0, 1.4]),
            runout_std=np.array([0.05, 0.05]),
        ),
        columns[1],
    ]
    with pytest.raises(DiagnosisError, match="2 runout point"):
        check_data(Observables(short), small_library(Observables(short)), models, noise)
    # a zero noise level would make any misfit "decisive"
    with pytest.raises(DiagnosisError, match="positive standard deviation"):
        noise_model(observables, library, runout_noise=0.0, profile_noise=0.0)
    unknown = [replace(c, runout_std=None) for c in columns]
    _, notes = noise_model(Observables(unknown), small_library(Observables(unknown)))
    assert len(notes) == 2 and "assumed std 0.1" in notes[0]


def test_library_round_trip(tmp_path):
    observables = Observables(two_columns())
    library = small_library(observables)
    library.save(tmp_path / "library.npz")
    loaded = Library.load(tmp_path / "library.npz")
    assert loaded.signature == library.signature
    assert np.array_equal(loaded.runs["base"].observed, library.runs["base"].observed)
    assert loaded.runs["base"].stage.tolist() == library.runs["base"].stage.tolist()
    assert loaded.packing_std() == pytest.approx(library.packing_std())
    loaded.check(observables, [Model()])
    with pytest.raises(Exception, match="no runs of model"):
        loaded.check(observables, [Model(), Model(MECHANISMS["cohesion"])])


# -- hidden mechanism in another solver's data (LIGGGHTS, Hertz contacts, its own packing and reading) --
# -- the profile: read as stated, noise as stated, never outvoting the runout by its row count --------
def profile_column(step_diameters, std=None):
    """A quartz column (L_i 2 cm, a = 2) with runout at 10 times and a profile every `step_diameters`
    real grain diameters, read in bins of 2 diameters at t/t* 5.5."""
    (column,) = synthetic_columns(aspect_ratios=(2.0,), profile_step_diameters=step_diameters)
    height = np.interp(column.profile_x, [0.0, 0.06], [0.03, 0.0])
    runout = np.linspace(0.3, 3.0, len(column.t_over_tstar))
    return replace(column, runout=runout, profile_height=height, profile_std=std)


def test_a_dense_profile_counts_no_more_than_a_sparse_one():
    """The same deposit at 3 and at 0.75 grain diameters per point: four times the rows, the same
    evidence (effective points and the chi^2 weight of a common offset within 10%)."""
    weights = {}
    for step in (3.0, 0.75):
        observables = Observables([profile_column(step)])
        noise, notes = noise_model(observables, small_library(observables, scale=1.0), profile_noise=5e-4)
        profile = observables.kind == "profile"
        rows = int(profile.sum())
        offset_chi2 = float(np.sum((1e-3 / noise.total[profile]) ** 2))  # a 1 mm offset of the whole profile
        weights[step] = (rows, noise.n_effective - int((~profile).sum()), offset_chi2)
        # the grain sizes enter the profile's std: d = 4 x 425 um model grains, 425 um real ones
        np.testing.assert_allclose(noise.measurement[profile], math.hypot(5e-4, 3 * 425e-6 / 2))
        assert np.all(noise.correlation[~profile] == 1.0) and noise.correlation[profile].min() >= 1.0
    (rows_sparse, eff_sparse, chi2_sparse), (rows_dense, eff_dense, chi2_dense) = weights[3.0], weights[0.75]
    assert rows_dense >= 3.9 * rows_sparse
    assert abs(eff_dense - eff_sparse) <= 1  # limited by the correlation length, not the sampling
    assert chi2_dense == pytest.approx(chi2_sparse, rel=0.1)
    assert eff_sparse < rows_sparse  # even the sparse one: bins + a model grain are wider than its step


def test_profile_std_from_the_file_is_honoured():
    observables = Observables([profile_column(3.0, std=np.full(46, 2e-3))])
    noise, notes = noise_model(observables, small_library(observables), profile_noise=5e-4)
    profile = observables.kind == "profile"
    assert noise.measurement[profile].min() > 2e-3 and "profile std from the file" in noise.source
