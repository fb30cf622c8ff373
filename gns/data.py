"""Training data: windows of C + 1 consecutive frames streamed from trajectory HDF5 files.

Nothing but the small per-file arrays (radius, particle_type) and attributes stays in memory; each
sample reads its C + 1 frames with one h5py slice, so memory is bounded by one batch whatever the
dataset's size.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from dem.trajectory import check_finite, open_trajectory, read_attrs
from gns.dataset import LAYOUT_KEYS, DatasetError, with_off_values
from gns.simulator import Context


@dataclass
class Batch:
    """G windows as one graph batch: position_sequence [N, C, 2] (m), next_position [N, 2] (m)."""

    position_sequence: torch.Tensor
    next_position: torch.Tensor
    context: Context

    def to(self, device: torch.device | str) -> Batch:
        return Batch(self.position_sequence.to(device), self.next_position.to(device), self.context.to(device))


class TrajectoryWindows:
    """All windows of C + 1 frames of a list of trajectory files; window k is read on demand."""

    def __init__(
        self,
        paths: Iterable[str | os.PathLike],
        n_input_frames: int,
        parameter_names: Iterable[str],
        dt_frame: float | None = None,
        off: dict | None = None,
    ):
        self.n_input_frames = n_input_frames
        self.parameter_names = list(parameter_names)
        self.files = []
        for path in map(Path, paths):
            if not path.exists():
                raise DatasetError(f"{path}: trajectory file listed in the dataset does not exist")
            # a truncated or damaged file: TrajectoryError naming it; a parameter it leaves out: off's
            attrs = with_off_values(read_attrs(path), off)
            missing = [k for k in self.parameter_names + list(LAYOUT_KEYS) + ["dt_frame"] if k not in attrs]
            if missing:
                raise DatasetError(f"{path}: trajectory attributes lack {missing}")
            if dt_frame is not None and abs(float(attrs["dt_frame"]) - dt_frame) > 1e-9 * dt_frame:
                raise DatasetError(f"{path}: dt_frame {attrs['dt_frame']} s differs from the dataset's {dt_frame} s")
            with open_trajectory(path) as f:
                n_frames = f["positions"].shape[0]
                radius = f["radius"][()]
                particle_type = f["particle_type"][()]
            if n_frames < n_input_frames + 1:
                raise DatasetError(
                    f"{path}: {n_frames} frames, too few for one GNS window of {n_input_frames + 1} frames "
                    f"({n_input_frames} input frames + 1 target)"
                )
            self.files.append(
                {
                    "path": path,
                    "n_windows": n_frames - n_input_frames,
                    "radius": radius,
                    "particle_type": particle_type.astype(np.int64),
                    "parameters": np.array([float(attrs[k]) for k in self.parameter_names]),
                    "layout": np.array([float(attrs[k]) for k in LAYOUT_KEYS]),
                }
            )
        if not self.files:
            raise DatasetError("no trajectory files given")
        self.offsets = np.cumsum([0] + [f["n_windows"] for f in self.files])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def locate(self, k: int) -> tuple[int, int]:
        """(file index, first frame) of window k."""
        i = int(np.searchsorted(self.offsets, k, side="right") - 1)
        return i, int(k - self.offsets[i])

    def window(self, k: int) -> tuple[np.ndarray, dict]:
        """positions [C + 1, N, 2] float32 (m) of window k, and its file's entry."""
        i, start = self.locate(k)
        entry = self.files[i]
        with open_trajectory(entry["path"]) as f:
            positions = f["positions"][start : start + self.n_input_frames + 1]
        check_finite(positions, str(entry["path"]), first_frame=start)
        return positions, entry

    def batch(self, indices: Iterable[int]) -> Batch:
        """Windows `indices` concatenated into one batch of disjoint graphs."""
        sequences, targets, types, radii, params, layouts, graph = [], [], [], [], [], [], []
        for g, k in enumerate(indices):
            positions, entry = self.window(int(k))
            sequences.append(positions[:-1].transpose(1, 0, 2))
            targets.append(positions[-1])
            types.append(entry["particle_type"])
            radii.append(entry["radius"])
            params.append(entry["parameters"])
            layouts.append(entry["layout"])
            graph.append(np.full(len(entry["radius"]), g))
        as_float = lambda arrays: torch.from_numpy(np.concatenate(arrays).astype(np.float32))  # noqa: E731
        context = Context(
            torch.from_numpy(np.concatenate(types)),
            as_float(radii),
            torch.from_numpy(np.stack(params).astype(np.float32)),
            torch.from_numpy(np.stack(layouts).astype(np.float32)),
            torch.from_numpy(np.concatenate(graph).astype(np.int64)),
        )
        return Batch(as_float(sequences), as_float(targets), context)
