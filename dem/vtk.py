"""A trajectory as a ParaView time series: one `.vtu` point file per frame and a `.pvd` collection.

Any trajectory HDF5 (dem/trajectory.py: a DEM run of any engine, or a GNS rollout) exports to a
folder

  <name>.pvd              the collection: one <DataSet timestep="t_k" file="<name>_<k>.vtu"/> per
                          frame, in time order, t_k = k * dt_frame (s, Trajectory.times)
  <name>_0000.vtu, ...    frame k: N points (one VTK vertex cell each) at (x, y, 0) (m, float32),
                          point data radius (m), velocity (m/s, [N, 3], z = 0), particle_type,
                          particle_id (the grain's index, for ParaView's pathline filters)

written with meshio (zlib-compressed binary XML). Open the `.pvd` in ParaView and show the points
as "Point Gaussian" scaled by `radius` (docs/workflow.md, "Looking at a run in ParaView").

The folder is written atomically: into a temporary folder beside it, renamed over it when every
file (the `.pvd` last) is complete. An existing folder is replaced only when it holds nothing but
`.vtu` and `.pvd` files (a previous export); anything else there is an ExportError.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import meshio
import numpy as np

from dem.atomic import atomic_dir
from dem.trajectory import Trajectory, read_trajectory

EXPORT_SUFFIXES = (".vtu", ".pvd")  # what an export folder holds (and all it may hold to be replaced)


class ExportError(ValueError):
    """The export cannot be written where asked; the message names the folder."""


@dataclass
class VtkExport:
    """What one export wrote: the collection, its frame files [T] in time order and their times [T] (s)."""

    pvd: Path
    frames: list[Path]
    times: np.ndarray


def frame_velocities(positions: np.ndarray, dt_frame: float) -> np.ndarray:
    """[T, N, 2] velocity (m/s) of every grain at every frame from positions [T, N, 2] (m) and the
    time between frames dt_frame (s), by finite differences (numpy.gradient): central differences
    (x[k+1] - x[k-1]) / (2 dt_frame) at interior frames, one-sided (x[1] - x[0]) / dt_frame and
    (x[T-1] - x[T-2]) / dt_frame at the first and last frame; zero for a single frame."""
    positions = np.asarray(positions, np.float64)
    if positions.shape[0] < 2:
        return np.zeros_like(positions)
    return np.gradient(positions, float(dt_frame), axis=0)


def points_3d(xy: np.ndarray) -> np.ndarray:
    """[N, 3] float32 points (x, y, 0) (m) from positions xy [N, 2] (m): ParaView wants 3D points."""
    xy = np.asarray(xy, np.float32)
    return np.concatenate([xy, np.zeros((xy.shape[0], 1), np.float32)], axis=1)


def frame_mesh(
    xy: np.ndarray,
    velocity: np.ndarray,
    radius: np.ndarray,
    particle_type: np.ndarray,
) -> meshio.Mesh:
    """One frame as a meshio point mesh: xy [N, 2] (m), velocity [N, 2] (m/s), radius [N] (m),
    particle_type [N]. (The frame's time is the .pvd's: meshio 5.3's .vtu writer drops field data.)"""
    n = xy.shape[0]
    return meshio.Mesh(
        points=points_3d(xy),
        cells=[("vertex", np.arange(n, dtype=np.int64).reshape(n, 1))],
        point_data={
            "radius": np.asarray(radius, np.float64),
            "velocity": points_3d(velocity),
            "particle_type": np.asarray(particle_type, np.int32),
            "particle_id": np.arange(n, dtype=np.int32),
        },
    )


def pvd_text(files: Sequence[str], times: Sequence[float]) -> str:
    """The `.pvd` collection (XML) listing frame files [T] (relative to the .pvd) at times [T] (s)."""
    if len(files) != len(times):
        raise ValueError(f"{len(files)} frame files but {len(times)} times")
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    collection = ET.SubElement(root, "Collection")
    for file, time in zip(files, times):
        ET.SubElement(collection, "DataSet", timestep=repr(float(time)), group="", part="0", file=str(file))
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def export_trajectory(
    trajectory: Trajectory,
    outdir: str | os.PathLike,
    name: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> VtkExport:
    """Write `trajectory` as <outdir>/<name>.pvd and <outdir>/<name>_<k>.vtu, one per frame (module
    docstring), atomically. name: default the folder's name. progress(fraction done) after each frame."""
    outdir = Path(outdir)
    name = name or outdir.name
    _check_replaceable(outdir)
    times = trajectory.times
    velocity = frame_velocities(trajectory.positions, float(trajectory.attrs["dt_frame"]))
    digits = max(4, len(str(trajectory.n_frames - 1)))
    files = [f"{name}_{k:0{digits}d}.vtu" for k in range(trajectory.n_frames)]
    with atomic_dir(outdir) as tmp:
        for k, file in enumerate(files):
            mesh = frame_mesh(trajectory.positions[k], velocity[k], trajectory.radius, trajectory.particle_type)
            meshio.write(tmp / file, mesh, file_format="vtu")
            if progress is not None:
                progress((k + 1) / len(files))
        (tmp / f"{name}.pvd").write_text(pvd_text(files, times))  # last: the collection lists complete frames
    return VtkExport(pvd=outdir / f"{name}.pvd", frames=[outdir / f for f in files], times=times)


def export_file(
    path: str | os.PathLike,
    outdir: str | os.PathLike,
    name: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> VtkExport:
    """Export the trajectory HDF5 at `path` (export_trajectory); name: default the file's stem. A
    file that is not a trajectory raises dem.trajectory.TrajectoryError naming it."""
    return export_trajectory(read_trajectory(path), outdir, name or Path(path).stem, progress)


def read_pvd(path: str | os.PathLike) -> tuple[list[Path], np.ndarray]:
    """([T] frame files, [T] times (s)) listed by a `.pvd` collection, in the order it lists them."""
    path = Path(path)
    try:
        datasets = ET.parse(path).getroot().findall("./Collection/DataSet")
    except (OSError, ET.ParseError) as exc:
        raise ExportError(f"{path}: not a readable .pvd collection ({exc})") from exc
    return [path.parent / d.get("file") for d in datasets], np.array([float(d.get("timestep")) for d in datasets])


def _check_replaceable(outdir: Path) -> None:
    if outdir.exists() and not outdir.is_dir():
        raise ExportError(f"{outdir}: exists and is not a folder")
    if outdir.is_dir():
        foreign = [p.name for p in outdir.iterdir() if not (p.is_file() and p.suffix in EXPORT_SUFFIXES)]
        if foreign:
            raise ExportError(
                f"{outdir}: holds {sorted(foreign)[:5]}, not only a previous export's .vtu/.pvd files; "
                "give an empty or new folder"
            )
