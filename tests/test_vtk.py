"""The ParaView export (dem/vtk.py, `python -m dem export-vtk`): a trajectory round-trips through
the .vtu files to float32 precision, the .pvd lists the frames in time order with their physical
times, and a file that is not a trajectory is refused naming the file."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest

from dem.trajectory import Trajectory, TrajectoryError, write_trajectory
from dem.vtk import ExportError, export_file, frame_velocities, read_pvd

ROOT = Path(__file__).resolve().parents[1]
DT = 0.0025  # s between frames
T, N = 5, 7


def small_trajectory() -> Trajectory:
    """T frames of N grains moving at constant velocity (1 + i, -0.5 i) mm/s, with an irrational offset."""
    rng = np.random.default_rng(3)
    start = rng.uniform(0.0, 0.05, (N, 2)) + np.pi * 1e-7
    velocity = np.stack([1 + np.arange(N), -0.5 * np.arange(N)], axis=1) * 1e-3
    positions = (start[None] + velocity[None] * (DT * np.arange(T))[:, None, None]).astype(np.float32)
    attrs = dict(
        engine="builtin",
        engine_version="test",
        L_i=0.02,
        H_i=0.04,
        aspect_ratio=2.0,
        material="quartz",
        dt_frame=DT,
        t_star=float(np.sqrt(0.04 / 9.81)),
        x_min=0.0,
        x_max=0.5,
        y_min=0.0,
        y_max=0.35,
        seed=0,
        friction=0.5,
        restitution=0.65,
    )
    radius = rng.uniform(0.0009, 0.0011, N)
    return Trajectory(positions, radius, np.zeros(N, np.int32), attrs)


@pytest.fixture
def trajectory_file(tmp_path):
    return write_trajectory(tmp_path / "case_001.h5", small_trajectory())


def test_every_frame_reads_back_with_the_same_positions_and_point_data(trajectory_file, tmp_path):
    traj = small_trajectory()
    export = export_file(trajectory_file, tmp_path / "vtk")
    assert len(export.frames) == T and export.pvd == tmp_path / "vtk" / "case_001.pvd"
    for k, path in enumerate(export.frames):
        mesh = meshio.read(path)
        assert mesh.points.shape == (N, 3) and mesh.points.dtype == np.float32
        np.testing.assert_array_equal(mesh.points[:, :2], traj.positions[k])  # float32 in, float32 out
        assert np.all(mesh.points[:, 2] == 0)
        np.testing.assert_allclose(mesh.point_data["radius"], traj.radius, rtol=1e-12)
        np.testing.assert_array_equal(mesh.point_data["particle_type"], traj.particle_type)
        np.testing.assert_array_equal(mesh.point_data["particle_id"], np.arange(N))
        velocity = mesh.point_data["velocity"]
        assert velocity.shape == (N, 3) and np.all(velocity[:, 2] == 0)
        # constant velocity: every finite difference recovers it (to the float32 rounding of positions)
        expected = np.stack([1 + np.arange(N), -0.5 * np.arange(N)], axis=1) * 1e-3
        np.testing.assert_allclose(velocity[:, :2], expected, atol=2e-5)


def test_the_pvd_lists_the_frames_in_time_order_with_physical_times(trajectory_file, tmp_path):
    export = export_file(trajectory_file, tmp_path / "vtk")
    datasets = ET.parse(export.pvd).getroot().findall("./Collection/DataSet")
    times = [float(d.get("timestep")) for d in datasets]
    files = [d.get("file") for d in datasets]
    assert times == pytest.approx(DT * np.arange(T), rel=1e-15) and np.all(np.diff(times) > 0)
    assert files == [p.name for p in export.frames] == sorted(files)
    assert all((export.pvd.parent / f).is_file() for f in files)
    assert read_pvd(export.pvd)[0] == export.frames


def test_velocity_is_central_inside_and_one_sided_at_the_ends():
    x = np.array([0.0, 1.0, 4.0, 9.0])[:, None, None] * np.ones((1, 1, 2))  # x = k^2
    v = frame_velocities(x, 0.5)[:, 0, 0]
    np.testing.assert_allclose(v, [2.0, 4.0, 8.0, 10.0])  # (1-0)/0.5, (4-0)/1, (9-1)/1, (9-4)/0.5
    assert np.all(frame_velocities(x[:1], 0.5) == 0)


def test_a_previous_export_is_replaced_and_a_foreign_folder_is_refused(trajectory_file, tmp_path):
    out = tmp_path / "vtk"
    export_file(trajectory_file, out, name="old")
    export_file(trajectory_file, out)
    assert sorted(p.name for p in out.iterdir()) == ["case_001.pvd"] + [f"case_001_{k:04d}.vtu" for k in range(T)]
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ExportError, match="notes.txt"):
        export_file(trajectory_file, out)
    assert (out / "notes.txt").exists() and not list(tmp_path.glob(".vtk.*"))  # nothing left behind


def test_cli_exports_a_file_and_names_a_file_that_is_not_a_trajectory(trajectory_file, tmp_path):
    cli = [sys.executable, "-m", "dem", "export-vtk"]
    done = subprocess.run(cli + [str(trajectory_file), str(tmp_path / "out")], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert read_pvd(tmp_path / "out" / "case_001.pvd")[1] == pytest.approx(DT * np.arange(T))
    other = tmp_path / "not_a_trajectory.h5"
    with h5py.File(other, "w") as f:
        f["data"] = np.arange(3)
    bad = subprocess.run(cli + [str(other), str(tmp_path / "bad")], cwd=ROOT, capture_output=True, text=True)
    assert bad.returncode != 0 and str(other) in bad.stderr and "positions" in bad.stderr
    assert not (tmp_path / "bad").exists()


def test_not_hdf5_at_all_is_an_error_naming_the_file(tmp_path):
    path = tmp_path / "notes.h5"
    path.write_text("not HDF5")
    with pytest.raises(TrajectoryError, match=str(path)):
        export_file(path, tmp_path / "vtk")
