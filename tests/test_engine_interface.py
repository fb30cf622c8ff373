"""The engine interface: selection, configuration, the builtin engine behind it, failures."""

import logging
import math
import shutil

import numpy as np
import pytest

from dem.case import CollapseCase
from dem.collapse import simulate_collapse
from dem.engines import EngineError, EngineNotInstalled, get_engine
from dem.engines.base import damping_ratio, restitution_from_damping_ratio, size_classes
from dem.engines.builtin import BuiltinEngine
from dem.packing import settle_column
from dem.trajectory import read_trajectory

HAS_LIGGGHTS = shutil.which("liggghts") is not None


@pytest.fixture(scope="module")
def tiny():
    """About 25 grains, 0.5 t* of collapse: runs in well under a second."""
    case = CollapseCase("quartz", 0.006, 1.0, 0.5, 0.6, size_scale=3.0, duration_over_tstar=0.5, name="tiny")
    return case, settle_column(case)


def test_auto_prefers_a_real_solver_and_says_why(caplog):
    caplog.set_level(logging.INFO, logger="dem.engines")
    engine = get_engine("auto")
    expected = "mfix" if shutil.which("mfixsolver") else "liggghts" if HAS_LIGGGHTS else "builtin"
    assert engine.name == expected
    assert f"using {expected}" in caplog.text and "mfixsolver" in caplog.text


def test_auto_falls_back_to_builtin_when_configured_solvers_are_missing(caplog):
    caplog.set_level(logging.INFO, logger="dem.engines")
    config = {"solvers": {"mfix": "/nonexistent/mfixsolver", "liggghts": "/nonexistent/liggghts"}}
    assert get_engine("auto", config).name == "builtin"
    assert "/nonexistent/liggghts" in caplog.text


def test_named_engine_not_installed_says_how_to_install():
    with pytest.raises(EngineNotInstalled, match="conda"):
        get_engine("mfix", {"solvers": {"mfix": "/nonexistent/mfixsolver"}})
    with pytest.raises(EngineNotInstalled, match="apt-get install liggghts"):
        get_engine("liggghts", {"solvers": {"liggghts": "/nonexistent/liggghts"}})


def test_bad_engine_names_and_solver_config():
    with pytest.raises(EngineError, match="unknown engine 'lammps'"):
        get_engine("lammps")
    with pytest.raises(EngineError, match="dem.solvers: unknown engine"):
        get_engine("builtin", {"solvers": {"lammps": "/usr/bin/lmp"}})
    with pytest.raises(EngineError, match="dem.solvers.liggghts"):
        get_engine("builtin", {"solvers": {"liggghts": 3}})


@pytest.mark.skipif(not HAS_LIGGGHTS, reason="liggghts not installed (apt-get install liggghts)")
def test_solver_path_is_configurable():
    path = shutil.which("liggghts")
    engine = get_engine("liggghts", {"solvers": {"liggghts": path}})
    assert engine.find_solver() == path
    assert engine.version().startswith("LIGGGHTS")


def test_builtin_engine_through_the_interface_matches_simulate_collapse(tiny, tmp_path):
    case, packing = tiny
    engine = get_engine("builtin")
    fractions = []
    trajectory = engine.simulate(case, packing, tmp_path / "run", progress=fractions.append, output=tmp_path / "out.h5")
    direct = simulate_collapse(case, packing)
    np.testing.assert_array_equal(trajectory.positions, direct.positions)
    assert trajectory.n_frames == case.n_frames and fractions[-1] == 1.0
    assert (tmp_path / "run" / "case.json").exists() and (tmp_path / "run" / "packing.h5").exists()
    assert "done in" in (tmp_path / "run" / "builtin.log").read_text()
    np.testing.assert_array_equal(read_trajectory(tmp_path / "out.h5").positions, direct.positions)


def test_builtin_engine_failure_names_the_deck(tiny, tmp_path):
    case, packing = tiny
    engine = BuiltinEngine()
    deck = engine.render(case, packing, tmp_path)
    deck.write_text(deck.read_text().replace('"friction": 0.5', '"friction": -1'))
    with pytest.raises(EngineError, match=f"deck {deck}.*friction"):
        engine.run(deck)
    assert "friction" in (tmp_path / "builtin.log").read_text()


def test_packing_of_another_case_is_refused(tiny, tmp_path):
    case, packing = tiny
    with pytest.raises(ValueError, match="settled for another case"):
        BuiltinEngine().simulate(case.replace(L_i=0.008), packing, tmp_path)


def test_size_classes_keep_restitution_within_tolerance():
    """Damping set per class pair from class masses: every real pair's e stays within tolerance."""
    rng = np.random.default_rng(1)
    mass = 2650 * math.pi / 6 * (1e-3 * rng.uniform(0.9, 1.1, 300)) ** 3
    kn, tolerance = 1000.0, 0.005
    for e in (0.3, 0.6, 0.9):
        index, class_mass, worst = size_classes(mass, (e,), tolerance, max_classes=60)
        assert worst <= tolerance and 1 < len(class_mass) < 60
        i, j = np.triu_indices(len(mass), 1)
        m_eff = mass[i] * mass[j] / (mass[i] + mass[j])
        mc = class_mass[index]
        m_eff_class = mc[i] * mc[j] / (mc[i] + mc[j])
        eta = 2 * np.sqrt(kn * m_eff_class) * damping_ratio(e)  # what the solver is given
        e_real = restitution_from_damping_ratio(eta / (2 * np.sqrt(kn * m_eff)))
        assert np.max(np.abs(e_real / e - 1)) <= worst + 1e-12
        e_wall = restitution_from_damping_ratio(np.sqrt(mc / mass) * damping_ratio(e))
        assert np.max(np.abs(e_wall / e - 1)) <= worst + 1e-12
    # one class is enough for equal grains; too few classes allowed reports the larger error
    assert len(size_classes(np.full(5, 1e-6), (0.5,), tolerance, 10)[1]) == 1
    assert size_classes(mass, (0.3,), tolerance, max_classes=2)[2] > tolerance


def test_dem_stage_row_to_deck_packing_run_and_figure(tiny, tmp_path, caplog):
    """pipeline.dem, the DEM stage's jobs: a case-table row -> deck -> settled packing -> run with
    the configured engine (stale scratch files cleared but a killed run's checkpoint, which it goes
    on from, the scratch folder removed) -> figure."""
    from pipeline.dem import draw_case, run_case, settle, write_deck

    case, packing = tiny
    caplog.set_level(logging.INFO)
    row = {
        "dataset": "tiny_set",
        "case_id": "case_000",
        "split": "train",
        "material": "quartz",
        "L_i": 0.006,
        "aspect_ratio": 1.0,
        "friction": 0.5,
        "restitution": 0.6,
        "size_scale": 3.0,
        "duration_over_tstar": 0.5,
    }
    assert write_deck(row, tmp_path / "deck.json") == case
    settled = settle(tmp_path / "deck.json", tmp_path / "packing.h5")
    np.testing.assert_array_equal(read_trajectory(tmp_path / "packing.h5").positions, packing.positions)
    assert settled.attrs["settled_height"] > 0
    work = tmp_path / "work"
    work.mkdir()
    (work / "stale.txt").write_text("a killed run's leftovers")

    def killed(fraction):  # a run killed midway left its checkpoint, which the rerun goes on from
        if fraction > 0.5:
            raise InterruptedError

    with pytest.raises(InterruptedError):
        simulate_collapse(case, packing, killed, checkpoint=work / "checkpoint.npz", checkpoint_every_s=0.0)
    trajectory = run_case(
        tmp_path / "deck.json",
        tmp_path / "packing.h5",
        tmp_path / "out.h5",
        "builtin",
        {},
        keep_work=False,
        work_dir=work,
    )
    np.testing.assert_array_equal(read_trajectory(tmp_path / "out.h5").positions, trajectory.positions)
    np.testing.assert_array_equal(trajectory.positions, simulate_collapse(case, packing).positions)
    assert trajectory.attrs["resumed_from_frame"] >= case.n_frames // 2 and "the run resumes from it" in caplog.text
    assert not work.exists()
    run_case(
        tmp_path / "deck.json",
        tmp_path / "packing.h5",
        tmp_path / "out.h5",
        "builtin",
        {},
        keep_work=True,
        work_dir=work,
    )
    assert (work / "case.json").exists()
    assert "collapse tiny_set/case_000: 100%" in caplog.text and "settled height" in caplog.text
    draw_case(tmp_path / "out.h5", tmp_path / "case.png", "connected_front")
    assert (tmp_path / "case.png").stat().st_size > 10_000


@pytest.mark.filterwarnings("ignore:Mean of empty slice", "ignore:invalid value encountered")  # 0.5 t*: no stopping
def test_runout_methods_stage_writes_study_figure_and_section(tiny, tmp_path):
    """pipeline.runout on one tiny builtin run (2 packings, 2 reruns; its own rollout as the GNS)."""
    import json

    from dem.trajectory import write_trajectory
    from pipeline.runout import run_runout_methods

    case, packing = tiny
    write_trajectory(tmp_path / "run.h5", simulate_collapse(case, packing))
    run = tmp_path / "run.h5"
    study = run_runout_methods(
        ["tiny"],
        [run],
        {"tiny": run},
        tmp_path / "methods.json",
        tmp_path / "methods.png",
        tmp_path / "report" / "runout.md",
        "connected_front",
        n_packings=2,
        n_reruns=2,
    )
    assert json.loads((tmp_path / "methods.json").read_text())["configured"]["method"] == "connected_front"
    assert study["mean"]["connected_front"]["gns_mse"] == 0.0 and study["mean"]["connected_front"]["gns_cases"] == 1
    text = (tmp_path / "report" / "runout.md").read_text()
    assert "method `connected_front`" in text and "](../methods.png)" in text and "| dense_front |" in text
    assert (tmp_path / "methods.png").stat().st_size > 10_000
