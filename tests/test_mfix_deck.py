"""MFIX deck rendering (golden files, keywords and types) and the .vtp particle reader, tested on
real .vtp files written by a real solver (LIGGGHTS `dump custom/vtk`). The MFIX run path itself
cannot be tested here (MFIX is not installable); see mfix_templates/README.md."""

import math
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from dem.case import CollapseCase
from dem.engines import EngineError, EngineNotInstalled, get_engine
from dem.engines.liggghts import FRAMES, read_dump_frames
from dem.engines.liggghts import render_deck as render_liggghts_deck
from dem.engines.mfix import MAX_PHASES, MfixEngine, read_vtp, read_vtp_frames, render_deck
from dem.trajectory import Trajectory

GOLDEN = Path(__file__).parent / "golden"
UPDATE = os.environ.get("UPDATE_GOLDEN") == "1"  # UPDATE_GOLDEN=1 pytest ... rewrites the golden files
CASE = CollapseCase(
    "quartz",
    0.006,
    1.0,
    friction=0.4,
    restitution=0.7,
    friction_wall=0.3,
    restitution_wall=0.5,
    size_scale=3.0,
    name="golden",
)


def lattice_packing(case: CollapseCase) -> Trajectory:
    """A fixed packing (no random numbers, no solver): case.n_particles grains on a square lattice,
    diameters d (1 + 0.1 sin(1.7 i))."""
    n = case.n_particles
    radius = 0.5 * case.diameter * (1 + 0.1 * np.sin(1.7 * np.arange(n)))
    pitch = 2.05 * radius.max()
    per_row = int(case.L_i / pitch)
    index = np.arange(n)
    positions = np.stack([(index % per_row + 0.5) * pitch, (index // per_row + 0.5) * pitch], axis=1)
    return Trajectory(positions[None].astype(np.float32), radius, np.zeros(n, np.int32), {})


def check_golden(name: str, text: str):
    path = GOLDEN / name
    if UPDATE:
        path.write_text(text)
    assert path.exists(), f"{path} missing: run with UPDATE_GOLDEN=1 once and review the files"
    assert text == path.read_text(), f"rendered {name} differs from {path} (UPDATE_GOLDEN=1 to accept)"


def test_decks_match_golden_files():
    packing = lattice_packing(CASE)
    deck, particles = render_deck(CASE, packing)
    check_golden("mfix_collapse.mfx", deck)
    check_golden("mfix_particle_input.dat", particles)
    deck, data = render_liggghts_deck(CASE, packing)
    check_golden("liggghts_in.collapse", deck)
    check_golden("liggghts_packing.data", data)


def parse_mfx(text: str) -> dict:
    """{KEYWORD: value text} from `KEY = value` pairs (several may share a line), comments dropped."""
    values = {}
    for line in text.splitlines():
        line = line.split("#")[0].split("!")[0]
        for key, value in re.findall(
            r"([A-Za-z_][A-Za-z0-9_]*(?:\([0-9:, ]+\))?)\s*=\s*"
            r"(.*?)(?=\s+[A-Za-z_][A-Za-z0-9_]*(?:\([0-9:, ]+\))?\s*=|$)",
            line,
        ):
            values[key.upper()] = value.strip()
    return values


def fortran(value: str):
    """Python value of a Fortran namelist literal: logical, quoted string or list of reals."""
    tokens = value.upper().split()
    if tokens and set(tokens) <= {".TRUE.", ".FALSE."}:
        flags = [t == ".TRUE." for t in tokens]
        return flags[0] if len(flags) == 1 else flags
    if value.startswith("'"):
        assert value.endswith("'"), value
        return value[1:-1]
    numbers = [float(v) for v in value.split()]
    return numbers[0] if len(numbers) == 1 else numbers


# MFIX 23.x keywords the template may use (names as in the MFIX 23 user guide's keyword list)
KNOWN = {
    "RUN_NAME",
    "DESCRIPTION",
    "UNITS",
    "RUN_TYPE",
    "TIME",
    "TSTOP",
    "DT",
    "DT_MAX",
    "DT_MIN",
    "ENERGY_EQ",
    "SPECIES_EQ",
    "MOMENTUM_X_EQ",
    "MOMENTUM_Y_EQ",
    "MOMENTUM_Z_EQ",
    "GRAVITY_X",
    "GRAVITY_Y",
    "GRAVITY_Z",
    "COORDINATES",
    "X_MIN",
    "X_MAX",
    "Y_MIN",
    "Y_MAX",
    "Z_MIN",
    "Z_MAX",
    "NO_K",
    "IMAX",
    "JMAX",
    "RO_G0",
    "MU_G0",
    "MMAX",
    "SOLIDS_MODEL",
    "D_P0",
    "RO_S0",
    "DES_COLL_MODEL",
    "DES_INTG_METHOD",
    "DES_INTERP_ON",
    "KN",
    "KN_W",
    "KT_FAC",
    "KT_W_FAC",
    "DES_ETAT_FAC",
    "DES_ETAT_W_FAC",
    "DES_EN_INPUT",
    "DES_EN_WALL_INPUT",
    "MEW",
    "MEW_W",
    "DTSOLID_FACTOR",
    "NFACTOR",
    "DES_NEIGHBOR_SEARCH",
    "NEIGHBOR_SEARCH_N",
    "GENER_PART_CONFIG",
    "PARTICLES",
    "BC_X_W",
    "BC_X_E",
    "BC_Y_S",
    "BC_Y_N",
    "BC_TYPE",
    "IC_X_W",
    "IC_X_E",
    "IC_Y_S",
    "IC_Y_N",
    "IC_EP_G",
    "IC_U_G",
    "IC_V_G",
    "IC_P_G",
    "IC_T_G",
    "WRITE_VTK_FILES",
    "TIME_DEPENDENT_FILENAME",
    "VTK_X_W",
    "VTK_X_E",
    "VTK_Y_S",
    "VTK_Y_N",
    "VTK_Z_B",
    "VTK_Z_T",
    "VTK_FILEBASE",
    "VTK_DATA",
    "VTK_DT",
    "VTK_PART_DIAMETER",
    "VTK_PART_VEL",
    "RES_DT",
}


def test_mfix_deck_keywords_and_types():
    packing = lattice_packing(CASE)
    deck, particles = render_deck(CASE, packing)
    assert "$" not in deck, "unfilled template placeholder"
    values = {key: fortran(value) for key, value in parse_mfx(deck).items()}
    unknown = {re.sub(r"\(.*", "", key) for key in values} - KNOWN
    assert not unknown, f"keywords not in the MFIX 23.x list: {unknown}"
    n_phases = int(values["MMAX"])
    assert 1 <= n_phases <= MAX_PHASES
    assert values["NO_K"] is True and values["RO_G0"] == 0.0 and values["Z_MAX"] == pytest.approx(CASE.diameter)
    assert values["UNITS"] == "SI" and values["GRAVITY_Y"] == pytest.approx(-9.81)
    for m in range(1, n_phases + 1):
        assert values[f"SOLIDS_MODEL({m})"] == "DEM" and values[f"RO_S0({m})"] == CASE.density
        assert 0.8 * CASE.diameter < values[f"D_P0({m})"] < 1.2 * CASE.diameter
    assert values["KN"] == values["KN_W"] == CASE.normal_stiffness
    assert values["KT_FAC"] == values["KT_W_FAC"] == pytest.approx(2 / 7)
    assert values["DES_ETAT_FAC"] == values["DES_ETAT_W_FAC"] == 0.5
    en = np.atleast_1d(values["DES_EN_INPUT"])
    assert len(en) == n_phases * (n_phases + 1) // 2 and np.all(en == 0.7)
    assert np.all(np.atleast_1d(values["DES_EN_WALL_INPUT"]) == 0.5) and values["MEW"] == 0.4 and values["MEW_W"] == 0.3
    assert values["DTSOLID_FACTOR"] == pytest.approx(50)
    assert values["WRITE_VTK_FILES"] is True and values["VTK_DATA(1)"] == "P"
    assert values["VTK_DT(1)"] == pytest.approx(CASE.frame_interval)
    assert values["VTK_PART_DIAMETER(1)"] is True and values["VTK_PART_VEL(1)"] is True
    assert values["TSTOP"] == pytest.approx((CASE.n_frames - 1) * CASE.frame_interval)
    assert values["GENER_PART_CONFIG"] is False and values["PARTICLES"] == CASE.n_particles


def test_particle_input_holds_the_packing():
    packing = lattice_packing(CASE)
    deck, particles = render_deck(CASE, packing)
    n_phases = int(fortran(parse_mfx(deck)["MMAX"]))
    rows = np.array(
        [
            [float(v) for v in line.split()]
            for line in particles.splitlines()
            if line and not line.startswith("!") and "=" not in line and not line[0].isalpha()
        ]
    )
    assert rows.shape == (CASE.n_particles, 7)
    np.testing.assert_array_equal(rows[:, :2], packing.positions[0].astype(float))
    np.testing.assert_allclose(rows[:, 3], 2 * packing.radius, rtol=1e-15)
    assert set(rows[:, 2].astype(int)) <= set(range(1, n_phases + 1)) and np.all(rows[:, 4] == CASE.density)
    # phases are size classes: a larger grain never sits in a lower phase
    order = np.argsort(rows[:, 3])
    assert np.all(np.diff(rows[order, 2]) >= 0)
    assert f"Particles = {CASE.n_particles}" in particles


def test_mfix_not_installed_fails_saying_how_to_install(tmp_path):
    if shutil.which("mfixsolver"):
        pytest.skip("mfixsolver is installed here")
    with pytest.raises(EngineNotInstalled, match="conda"):
        get_engine("mfix")
    engine = MfixEngine()
    with pytest.raises(EngineNotInstalled, match="dem.solvers.mfix"):
        engine.simulate(CASE, lattice_packing(CASE), tmp_path)


@pytest.fixture(scope="module")
def liggghts_vtp(tmp_path_factory):
    """Real .vtp files: a short LIGGGHTS run writing both dump custom (text) and custom/vtk frames."""
    if shutil.which("liggghts") is None:
        pytest.skip("liggghts not installed (apt-get install liggghts): no solver to write real .vtp files")
    case = CASE.replace(duration_over_tstar=0.2)
    packing = lattice_packing(case)
    work = tmp_path_factory.mktemp("vtp")
    engine = get_engine("liggghts")
    engine.render(case, packing, work)
    deck_text, _ = render_liggghts_deck(case, packing, vtk=True)
    (work / "in.collapse").write_text(deck_text)
    engine.run(work / "in.collapse")
    return case, work


def test_vtp_reader_reads_real_solver_output(liggghts_vtp):
    case, work = liggghts_vtp
    files = sorted((work / FRAMES).glob("particles_*.vtp"))
    positions, radius = read_vtp_frames(files, case.n_frames, case.n_particles)
    dump_positions, dump_radius = read_dump_frames(work / FRAMES, case.n_frames, case.n_particles)
    np.testing.assert_allclose(radius, dump_radius, rtol=1e-8)
    np.testing.assert_allclose(positions, dump_positions, rtol=0, atol=1e-8)  # Points are Float32 in the file
    assert np.ptp(positions[:, :, 1]) > 0  # the grains moved: not the same frame read again
    points, data = read_vtp(files[0])
    assert points.shape == (case.n_particles, 3) and {"id", "radius", "mass"} <= set(data)
    np.testing.assert_allclose(
        data["mass"][np.argsort(data["id"])], [case.sphere_mass(2 * r) for r in radius], rtol=1e-6
    )


def test_vtp_reader_refuses_truncated_and_foreign_files(liggghts_vtp, tmp_path):
    case, work = liggghts_vtp
    files = sorted((work / FRAMES).glob("particles_*.vtp"))
    text = files[1].read_text()
    truncated = tmp_path / "PARTICLES_0001.vtp"
    truncated.write_text(text[: len(text) // 2])
    with pytest.raises(EngineError, match="PARTICLES_0001.vtp: .*truncated"):
        read_vtp(truncated)
    foreign = tmp_path / "PARTICLES_0002.vtp"
    foreign.write_text('<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid"><UnstructuredGrid/></VTKFile>\n')
    with pytest.raises(EngineError, match="not a VTK PolyData"):
        read_vtp(foreign)
    with pytest.raises(EngineError, match="expected 9 particle .vtp frames, found 2"):
        read_vtp_frames([truncated, foreign], 9, case.n_particles)
    garbled = tmp_path / "PARTICLES_0003.vtp"
    garbled.write_text(text.replace('format="ascii"', 'format="binary"', 1))
    with pytest.raises(EngineError, match="PARTICLES_0003.vtp: unreadable VTK data"):
        read_vtp(garbled)


def test_mfix_engine_reads_vtp_frames_into_a_trajectory(liggghts_vtp, tmp_path):
    """MfixEngine.collect on .vtp frames named as MFIX names them; a missing frame writes no HDF5."""
    case, work = liggghts_vtp
    files = sorted((work / FRAMES).glob("particles_*.vtp"), key=lambda p: int(re.search(r"(\d+)", p.name).group(1)))
    for k, path in enumerate(files):
        shutil.copy(path, tmp_path / f"PARTICLES_{k:04d}.vtp")
    packing = lattice_packing(case)
    engine = MfixEngine("/nonexistent/mfixsolver")
    output = tmp_path / "out.h5"
    trajectory = engine.collect(case, packing, tmp_path, output)
    assert trajectory.n_frames == case.n_frames and trajectory.attrs["engine"] == "mfix"
    np.testing.assert_allclose(trajectory.positions[0], packing.positions[0], atol=1e-7)
    assert output.exists()
    output.unlink()
    (tmp_path / f"PARTICLES_{len(files) - 1:04d}.vtp").unlink()
    with pytest.raises(EngineError, match=f"expected {case.n_frames} particle .vtp frames, found {len(files) - 1}"):
        engine.collect(case, packing, tmp_path, output)
    assert not output.exists()


def test_phase_count_respects_mfix_limit_and_reports_error():
    deck, _ = render_deck(CASE.replace(restitution=0.3), lattice_packing(CASE))
    n_phases = int(fortran(parse_mfx(deck)["MMAX"]))
    error = float(re.search(r"within ([\d.]+)%", deck).group(1)) / 100
    assert n_phases <= MAX_PHASES and error < 0.05
    assert math.isfinite(error)
