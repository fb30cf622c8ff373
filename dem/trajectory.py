"""The trajectory HDF5 file: one writer, one reader, for every engine and for GNS rollouts.

Layout (see ARCHITECTURE.md, "Trajectory HDF5"):
  positions      [T, N, 2] float32  particle centres (m), frame k at t = k * dt_frame
  radius         [N]       float64  (m)
  particle_type  [N]       int32    0 = grain (the only kind so far; walls are not particles)
  attributes: engine, engine_version, every physical parameter of the case (CollapseCase
  .physical_parameters(): L_i, H_i, aspect_ratio, material, friction, restitution, ...),
  dt_frame (s), t_star (s), domain bounds (x_min, x_max, y_min, y_max in m), seed.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from dem.atomic import atomic_path

if TYPE_CHECKING:
    from dem.case import CollapseCase

REQUIRED_ATTRS = (
    "engine",
    "engine_version",
    "L_i",
    "H_i",
    "aspect_ratio",
    "material",
    "dt_frame",
    "t_star",
    "x_min",
    "x_max",
    "y_min",
    "y_max",
    "seed",
    "friction",
    "restitution",
)
DATASETS = ("positions", "radius", "particle_type")
GRAIN = 0
# what h5py raises on a damaged file: truncated (OSError at open), a corrupt header or heap
# (KeyError, RuntimeError when an object or attribute is read)
UNREADABLE = (OSError, KeyError, RuntimeError)


class TrajectoryError(ValueError):
    """A trajectory file or array breaks the contract; the message names the file and item."""


@dataclass
class Trajectory:
    positions: np.ndarray  # [T, N, 2] float32 (m)
    radius: np.ndarray  # [N] (m)
    particle_type: np.ndarray  # [N] int32
    attrs: dict = field(default_factory=dict)
    source: str = ""  # the file it was read from, for error messages (not written)

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def n_particles(self) -> int:
        return self.positions.shape[1]

    @property
    def times(self) -> np.ndarray:
        """[T] physical time of each frame (s)."""
        return np.arange(self.n_frames) * float(self.attrs["dt_frame"])

    @property
    def t_over_tstar(self) -> np.ndarray:
        """[T] frame times in units of t* = sqrt(H_i / g)."""
        return self.times / float(self.attrs["t_star"])

    def validate(self, where: str = "trajectory") -> Trajectory:
        pos = self.positions
        if pos.ndim != 3 or pos.shape[2] != 2:
            raise TrajectoryError(f"{where}: positions must be [T, N, 2], got {pos.shape}")
        n = pos.shape[1]
        if self.radius.shape != (n,) or self.particle_type.shape != (n,):
            raise TrajectoryError(
                f"{where}: radius {self.radius.shape} and particle_type {self.particle_type.shape} must both be [{n}]"
            )
        missing = [k for k in REQUIRED_ATTRS if k not in self.attrs]
        if missing:
            raise TrajectoryError(f"{where}: missing attribute(s) {missing}")
        check_finite(pos, where)
        return self


def check_finite(positions: np.ndarray, where: str, first_frame: int = 0) -> None:
    """TrajectoryError naming `where`, the dataset and the first frame and grain when positions
    [T, N, 2] (frames first_frame.. of a file) hold a NaN or an infinity."""
    bad = ~np.isfinite(positions)
    if bad.any():
        frame, grain, _ = np.argwhere(bad)[0]
        frames = np.flatnonzero(bad.any(axis=(1, 2)))
        raise TrajectoryError(
            f"{where}: dataset 'positions' is not finite at frame {first_frame + frame}, grain {grain} "
            f"({int(bad.sum())} value(s) in {len(frames)} frame(s), frames {first_frame + frames[0]}.."
            f"{first_frame + frames[-1]})"
        )


def engine_attrs(case: CollapseCase, engine: str, engine_version: str) -> dict:
    """Trajectory attributes every engine writes for a dem.case.CollapseCase (the contract above)."""
    attrs = case.physical_parameters()
    attrs.update(
        engine=engine,
        engine_version=engine_version,
        dt_frame=case.frame_interval,
        x_min=0.0,
        x_max=case.box_width,
        y_min=0.0,
        y_max=case.box_height,
    )
    return attrs


def write_trajectory(path: str | os.PathLike, trajectory: Trajectory) -> Path:
    """Write `trajectory` to `path` atomically (temp file, then rename)."""
    path = Path(path)
    trajectory.validate(str(path))
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            f.create_dataset(
                "positions",
                data=np.asarray(trajectory.positions, np.float32),
                compression="gzip",
                compression_opts=4,
                shuffle=True,
                chunks=(1,) + trajectory.positions.shape[1:],
            )
            f.create_dataset("radius", data=np.asarray(trajectory.radius, np.float64))
            f.create_dataset("particle_type", data=np.asarray(trajectory.particle_type, np.int32))
            for key, value in trajectory.attrs.items():
                f.attrs[key] = "" if value is None else value
    return path


@contextlib.contextmanager
def open_trajectory(path: str | os.PathLike) -> Iterator[h5py.File]:
    """The trajectory file at `path` open for reading, its datasets present: the one way every
    reader opens one. A missing, truncated or damaged file is a TrajectoryError naming it."""
    path = Path(path)
    if not path.exists():
        raise TrajectoryError(f"{path}: no such trajectory file")
    try:
        with h5py.File(path, "r") as f:
            for key in DATASETS:
                if key not in f:
                    raise TrajectoryError(f"{path}: missing dataset {key!r}")
            yield f
    except UNREADABLE as exc:
        raise TrajectoryError(f"{path}: not a readable HDF5 file, truncated or damaged? ({exc})") from exc


def read_trajectory(path: str | os.PathLike, frames: slice | np.ndarray | None = None) -> Trajectory:
    """Read a trajectory file; `frames` (a slice or index array) reads only those frames."""
    path = Path(path)
    with open_trajectory(path) as f:
        positions = f["positions"][frames if frames is not None else slice(None)]
        traj = Trajectory(
            positions=np.asarray(positions, np.float32),
            radius=f["radius"][()],
            particle_type=f["particle_type"][()],
            attrs=_plain_attrs(f.attrs),
            source=str(path),
        )
    return traj.validate(str(path))


def read_attrs(path: str | os.PathLike) -> dict:
    """The attributes of a trajectory file without loading its positions."""
    with open_trajectory(path) as f:
        return _plain_attrs(f.attrs)


def _plain_attrs(attrs) -> dict:
    out = {}
    for key, value in attrs.items():
        if isinstance(value, bytes):
            value = value.decode()
        elif isinstance(value, np.generic):
            value = value.item()
        out[key] = value
    return out
