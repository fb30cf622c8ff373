"""Case validation, the trajectory HDF5 contract, atomic writes and the runout measure."""

import math

import h5py
import numpy as np
import pytest

from dem.case import CaseError, CollapseCase, get_material
from dem.runout import RunoutMethod, deposit_mask, deposit_profile, final_height, runout_at
from dem.trajectory import Trajectory, TrajectoryError, read_trajectory, write_trajectory


@pytest.mark.parametrize(
    "changes, field",
    [
        (dict(material="marble"), "material"),
        (dict(L_i=-0.02), "L_i"),
        (dict(L_i=math.nan), "L_i"),
        (dict(aspect_ratio=0.0), "aspect_ratio"),
        (dict(friction=-0.1), "friction"),
        (dict(friction_wall=math.inf), "friction_wall"),
        (dict(restitution=0.0), "restitution"),
        (dict(restitution=1.2), "restitution"),
        (dict(restitution_wall=-0.5), "restitution_wall"),
        (dict(size_scale=-1.0), "size_scale"),
        (dict(aspect_ratio=20.0), "column of height"),
        (dict(L_i=0.45), "L_i"),
        (dict(dt_over_contact_time=0.5), "dt_over_contact_time"),
        (dict(seed=-1), "seed"),
    ],
)
def test_bad_case_fields_are_named(changes, field):
    base = dict(material="quartz", L_i=0.02, aspect_ratio=2.0, friction=0.5, restitution=0.6)
    with pytest.raises(CaseError, match=field):
        CollapseCase(**{**base, **changes})


def test_custom_material_and_errors():
    sand = get_material(dict(name="glass", diameter=1e-3, density=2500, solid_fraction=0.6))
    assert CollapseCase(sand, 0.05, 1.0, 0.3, 0.9).diameter == pytest.approx(1e-3)
    with pytest.raises(CaseError, match="diameter"):
        get_material(dict(name="glass", diameter=-1e-3, density=2500, solid_fraction=0.6))
    with pytest.raises(CaseError, match="solid_fraction"):
        get_material(dict(name="glass", diameter=1e-3, density=2500))


def test_derived_scales_follow_the_paper():
    case = CollapseCase("quartz", 0.02, 6.0, 0.5, 0.65)
    assert case.H_i == pytest.approx(0.12)
    assert case.t_star == pytest.approx(math.sqrt(0.12 / 9.81))
    assert case.n_frames == 101 and case.frame_interval == pytest.approx(case.t_star / 25)
    # wall values follow the grain values unless set, also through replace()
    assert case.replace(friction=0.8).resolved_friction_wall == 0.8
    assert case.replace(friction_wall=0.2).resolved_friction_wall == 0.2
    assert CollapseCase.from_dict(case.to_dict()) == case
    with pytest.raises(CaseError, match=r"case: unknown key\(s\) \['mu'\]"):
        CollapseCase.from_dict({**case.to_dict(), "mu": 0.3})
    old = {k: v for k, v in case.to_dict().items() if k != "L_i"}
    with pytest.raises(CaseError, match="column_length is now L_i"):
        CollapseCase.from_dict({**old, "column_length": 0.02})


def _trajectory(n_frames=3, n=4):
    positions = np.random.default_rng(0).uniform(0, 0.01, (n_frames, n, 2)).astype(np.float32)
    attrs = CollapseCase("quartz", 0.02, 1.0, 0.5, 0.65).physical_parameters()
    attrs.update(engine="test", engine_version="0", dt_frame=0.01, x_min=0.0, x_max=0.5, y_min=0.0, y_max=0.35)
    return Trajectory(positions, np.full(n, 2e-4), np.zeros(n, np.int32), attrs)


def test_trajectory_round_trip(tmp_path):
    traj = _trajectory()
    write_trajectory(tmp_path / "t.h5", traj)
    back = read_trajectory(tmp_path / "t.h5")
    assert np.array_equal(back.positions, traj.positions)
    assert back.attrs["engine"] == "test" and back.attrs["L_i"] == pytest.approx(0.02)
    assert np.allclose(back.times, [0, 0.01, 0.02])
    assert read_trajectory(tmp_path / "t.h5", frames=slice(1, 2)).n_frames == 1


def test_failed_write_leaves_nothing(tmp_path):
    traj = _trajectory()
    traj.attrs["bad"] = object()  # h5py cannot store it: the write fails half-way
    with pytest.raises(TypeError):
        write_trajectory(tmp_path / "t.h5", traj)
    assert list(tmp_path.iterdir()) == []


def test_broken_files_are_named(tmp_path):
    path = tmp_path / "x.h5"
    with h5py.File(path, "w") as f:
        f["positions"] = np.zeros((2, 3, 2))
    with pytest.raises(TrajectoryError, match=r"x\.h5.*radius"):
        read_trajectory(path)
    path.write_bytes(b"not hdf5")
    with pytest.raises(TrajectoryError, match=r"x\.h5"):
        read_trajectory(path)
    traj = _trajectory()
    del traj.attrs["t_star"]
    with pytest.raises(TrajectoryError, match="t_star"):
        write_trajectory(tmp_path / "y.h5", traj)


def test_runout_ignores_grains_rolling_alone_ahead():
    r = 1e-3
    row = np.stack([np.arange(30) * 2 * r + r, np.full(30, r)], axis=1)  # touching grains
    loner = np.array([[0.5, r]])  # far ahead
    positions = np.vstack([row, loner])
    radius = np.full(len(positions), r)
    mask = deposit_mask(positions, radius)
    assert mask[:30].all() and not mask[30]
    # the 8 leading grains of the row: mean of their leading edges
    expected = np.mean(row[-8:, 0] + r)
    assert RunoutMethod("connected_front").front_position(positions, radius) == pytest.approx(expected)
    x, height = deposit_profile(positions, radius)
    assert height.max() == pytest.approx(2 * r) and x.max() < 0.1
    assert final_height(positions, radius) == pytest.approx(2 * r)


def test_runout_at_refuses_times_outside_the_window():
    traj = _trajectory()
    with pytest.raises(ValueError, match="outside the simulated window"):
        runout_at(traj, [0.5, 100.0], "connected_front")


def test_one_case_cli_writes_hdf5_and_figure(tmp_path):
    from dem.__main__ import main

    out = tmp_path / "case.h5"
    assert main(["--size-scale", "4", "--aspect-ratio", "1", "--out", str(out)]) == 0
    traj = read_trajectory(out)
    assert traj.attrs["engine"] == "builtin" and traj.n_frames == 101
    assert out.with_suffix(".png").stat().st_size > 10_000
