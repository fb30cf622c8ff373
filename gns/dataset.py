"""A training-ready dataset: trajectory HDF5 files split into train/valid/test, plus the metadata
the GNS needs (frame interval, bounds, normalisation statistics, parameter ranges).

Metadata JSON (written by `build_dataset`, read by `load_dataset_metadata`):
  name                  dataset name
  splits                {"train": [paths], "valid": [...], "test": [...]}  trajectory HDF5 files
  dt_frame              s between frames; the same for every trajectory of the dataset
  dim                   2
  bounds                [[x_min, x_max], [y_min, y_max]] (m), union over the trajectories
  n_particles           {"min", "max", "mean"} grains per trajectory
  velocity_mean/_std    [2] position change per frame x[t] - x[t-1] (m), training split only
  acceleration_mean/_std [2] x[t+1] - 2 x[t] + x[t-1] (m per frame^2), training split only
  parameter_ranges      {"friction", "restitution"[, a mechanism's parameter], "L_i", "H_i", "aspect_ratio":
                        [min, max]}, all splits; the DEM parameters first, in the order the GNS takes them
  material_diameter     mean simulated grain diameter 2r over all grains of all trajectories (m)
  sequence_length       frames of the shortest trajectory (sequence_length_max: the longest)
  n_cases               {"train", "valid", "test"}; materials, engines: sorted lists
  parameter_off         (only where given) {parameter: its off value, a number or the name of the
                        parameter whose value it takes}: what a trajectory that does not record a
                        parameter had (a base model's run in an extended model's dataset)
Trajectories are read one at a time, so the dataset never has to fit in memory.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dem.atomic import write_json
from dem.trajectory import TrajectoryError, read_attrs, read_trajectory

if TYPE_CHECKING:
    from dem.runout import RunoutMethod

SPLITS = ("train", "valid", "test")
DEM_PARAMETERS = ("friction", "restitution")  # the paper's model; an extended model's dataset adds its own
LAYOUT_KEYS = ("L_i", "H_i")  # the initial layout of a case: a GNS input beside the DEM parameters
STATISTICS = ("velocity_mean", "velocity_std", "acceleration_mean", "acceleration_std")
LAYOUT = ("L_i", "H_i", "aspect_ratio")
REQUIRED_KEYS = (
    "name",
    "splits",
    "dt_frame",
    "dim",
    "bounds",
    "n_particles",
    "velocity_mean",
    "velocity_std",
    "acceleration_mean",
    "acceleration_std",
    "parameter_ranges",
    "material_diameter",
    "sequence_length",
)
DT_RTOL = 1e-9


class DatasetError(ValueError):
    """A dataset or its metadata breaks the contract; the message names the file and key."""


def with_off_values(attrs: dict, off: dict | None) -> dict:
    """Trajectory attributes `attrs` with each parameter of `off` (metadata's parameter_off) that
    they do not record set to its off value: a number, or the value of the parameter it names."""
    if not off:
        return attrs
    filled = dict(attrs)
    for name, value in off.items():
        if name not in filled:
            filled[name] = float(filled[value]) if isinstance(value, str) else float(value)
    return filled


class _RunningMoments:
    """Per-component mean and variance of [*, 2] samples, merged batch by batch (Chan et al.)."""

    def __init__(self, dim: int = 2):
        self.count = 0
        self.mean = np.zeros(dim)
        self.m2 = np.zeros(dim)

    def add(self, samples: np.ndarray) -> None:
        samples = samples.reshape(-1, samples.shape[-1]).astype(np.float64)
        n = len(samples)
        if n == 0:
            return
        mean = samples.mean(axis=0)
        m2 = ((samples - mean) ** 2).sum(axis=0)
        total = self.count + n
        delta = mean - self.mean
        self.mean = self.mean + delta * n / total
        self.m2 = self.m2 + m2 + delta**2 * self.count * n / total
        self.count = total

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(self.m2 / self.count)


def build_dataset(
    splits: dict[str, list[str]],
    out_path: str | os.PathLike,
    name: str,
    parameters: tuple[str, ...] | list[str] = DEM_PARAMETERS,
    off: dict | None = None,
) -> dict:
    """Scan the trajectories of `splits` ({"train"|"valid"|"test": [HDF5 paths]}) one at a time and
    write the metadata JSON atomically at `out_path`. parameters: the DEM parameters the GNS takes
    (trajectory attributes; the paper's (mu, e), or an extended model's). off: {parameter: off
    value} of the parameters a trajectory may leave out (with_off_values; a base model's runs in
    an extended model's dataset), recorded as parameter_off. Returns the metadata dict."""
    unknown = set(splits) - set(SPLITS)
    if unknown:
        raise DatasetError(f"dataset {name}: unknown split(s) {sorted(unknown)}; allowed: {list(SPLITS)}")
    splits = {s: [str(p) for p in splits.get(s, [])] for s in SPLITS}
    if not splits["train"]:
        raise DatasetError(f"dataset {name}: the train split is empty, so there are no normalisation statistics")

    dt_frame = dt_source = None
    bounds = np.array([[np.inf, -np.inf], [np.inf, -np.inf]])
    n_particles, frames, diameters = [], [], _RunningMoments(dim=1)
    ranges = {k: [np.inf, -np.inf] for k in tuple(parameters) + LAYOUT}
    velocity, acceleration = _RunningMoments(), _RunningMoments()
    materials, engines = set(), set()
    for split in SPLITS:
        for path in splits[split]:
            traj = read_trajectory(path)
            a = with_off_values(traj.attrs, off)
            if traj.n_frames < 3:
                raise DatasetError(f"{path}: {traj.n_frames} frame(s); a dataset needs >= 3 for accelerations")
            if dt_frame is None:
                dt_frame, dt_source = float(a["dt_frame"]), path
            elif not math.isclose(float(a["dt_frame"]), dt_frame, rel_tol=DT_RTOL):
                raise DatasetError(
                    f"{path}: dt_frame = {a['dt_frame']} s differs from {dt_frame} s of {dt_source}; "
                    f"every trajectory of dataset {name} must share one output_interval"
                )
            bounds[:, 0] = np.minimum(bounds[:, 0], [a["x_min"], a["y_min"]])
            bounds[:, 1] = np.maximum(bounds[:, 1], [a["x_max"], a["y_max"]])
            n_particles.append(traj.n_particles)
            frames.append(traj.n_frames)
            diameters.add(2.0 * np.asarray(traj.radius, np.float64)[:, None])
            absent = [key for key in ranges if key not in a]
            if absent:
                raise DatasetError(f"{path}: no attribute(s) {absent}; dataset {name} takes {list(ranges)}")
            for key in ranges:
                ranges[key] = [min(ranges[key][0], float(a[key])), max(ranges[key][1], float(a[key]))]
            materials.add(str(a["material"]))
            engines.add(str(a["engine"]))
            if split == "train":
                x = traj.positions.astype(np.float64)
                velocity.add(x[1:] - x[:-1])
                acceleration.add(x[2:] - 2 * x[1:-1] + x[:-2])

    metadata = {
        "name": name,
        "splits": splits,
        "dt_frame": dt_frame,
        "dim": 2,
        "bounds": bounds.tolist(),
        "n_particles": {
            "min": int(min(n_particles)),
            "max": int(max(n_particles)),
            "mean": float(np.mean(n_particles)),
        },
        "velocity_mean": velocity.mean.tolist(),
        "velocity_std": velocity.std.tolist(),
        "acceleration_mean": acceleration.mean.tolist(),
        "acceleration_std": acceleration.std.tolist(),
        "parameter_ranges": ranges,
        "material_diameter": float(diameters.mean[0]),
        "sequence_length": int(min(frames)),
        "sequence_length_max": int(max(frames)),
        "n_cases": {s: len(splits[s]) for s in SPLITS},
        "materials": sorted(materials),
        "engines": sorted(engines),
    }
    if off:
        metadata["parameter_off"] = dict(off)
    write_json(out_path, metadata)
    return metadata


def load_dataset_metadata(path: str | os.PathLike) -> dict:
    """Read and check a metadata JSON written by build_dataset; errors name the file and key."""
    path = Path(path)
    try:
        metadata = json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetError(f"{path}: no such dataset metadata file") from None
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(metadata, dict):
        raise DatasetError(f"{path}: expected a JSON object, got {type(metadata).__name__}")
    missing = [k for k in REQUIRED_KEYS if k not in metadata]
    if missing:
        stats = [k for k in missing if k.startswith(("velocity_", "acceleration_"))]
        what = "no normalisation statistics: " if stats else ""
        raise DatasetError(f"{path}: {what}missing key(s) {missing}")
    splits = metadata["splits"]
    if not isinstance(splits, dict) or set(splits) != set(SPLITS):
        raise DatasetError(f"{path}: key 'splits' must map exactly {list(SPLITS)} to lists of trajectory files")
    for key in ("velocity_mean", "velocity_std", "acceleration_mean", "acceleration_std"):
        value = metadata[key]
        if not (
            isinstance(value, list)
            and len(value) == metadata["dim"]
            and all(isinstance(v, (int, float)) and math.isfinite(v) for v in value)
        ):
            raise DatasetError(f"{path}: key {key!r} must be {metadata['dim']} finite numbers, got {value!r}")
    for key in ("velocity_std", "acceleration_std"):
        if min(metadata[key]) <= 0:
            raise DatasetError(
                f"{path}: key {key!r} has a zero component {metadata[key]}; "
                "normalising by it would divide by zero (grains never moved?)"
            )
    if not (isinstance(metadata["dt_frame"], (int, float)) and metadata["dt_frame"] > 0):
        raise DatasetError(f"{path}: key 'dt_frame' must be a positive number (s), got {metadata['dt_frame']!r}")
    return metadata


def dataset_paths(metadata: dict) -> list[tuple[str, str]]:
    """[(split, trajectory path)] in split order."""
    return [(s, p) for s in SPLITS for p in metadata["splits"][s]]


def read_metadata(path: str | os.PathLike) -> dict:
    """A dataset's metadata (load_dataset_metadata's JSON), checked for what the GNS needs."""
    metadata = load_dataset_metadata(path)
    missing = [
        k
        for k in STATISTICS + ("parameter_ranges", "dt_frame", "bounds", "material_diameter", "splits")
        if k not in metadata
    ]
    if missing:
        raise DatasetError(f"{path}: dataset metadata lacks {missing}; rebuild it with gns.dataset.build_dataset")
    for key in STATISTICS:
        if len(metadata[key]) != 2 or not np.all(np.isfinite(metadata[key])):
            raise DatasetError(f"{path}: {key} must be two finite numbers, got {metadata[key]}")
    absent = [k for k in LAYOUT_KEYS if k not in metadata["parameter_ranges"]]
    if absent:
        raise DatasetError(f"{path}: parameter_ranges lacks {absent} (the initial layout is a model input)")
    return metadata


def split_paths(metadata: dict, split: str) -> list[str]:
    """Trajectory files of one split ("train", "valid", "test"); an empty split is an error."""
    paths = metadata["splits"].get(split) or []
    if not paths:
        raise DatasetError(
            f"dataset {metadata.get('name', '?')}: the {split} split is empty; "
            "the GNS needs train, valid and test cases"
        )
    return list(paths)


def read_training_attrs(metadata: dict) -> list[dict]:
    """Attributes of a dataset's training trajectories (metadata from read_metadata), without
    loading their positions."""
    return [read_attrs(path) for path in split_paths(metadata, "train")]


def plot_dataset(metadata: dict, path: str | os.PathLike, runout: RunoutMethod | dict | str) -> dict:
    """Summary figure of a dataset: the cases in parameter space coloured by split, and every
    case's runout curve L*(t/t*) (read by `runout`, a dem.runout.RunoutMethod, config dict or
    name) coloured by friction. Returns {trajectory path: final L*}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.plots import save_figure
    from dem.runout import RunoutMethod

    runout = RunoutMethod.from_config(runout)

    fig, (ax_p, ax_r) = plt.subplots(1, 2, figsize=(11, 4.2))
    ranges = metadata["parameter_ranges"]
    # the varied parameters, a mechanism's first (the one an extended model's dataset adds)
    order = [k for k in ranges if k not in DEM_PARAMETERS + LAYOUT] + list(DEM_PARAMETERS + LAYOUT)
    varied = [k for k in order if ranges[k][1] > ranges[k][0] and k != "H_i"]
    x_key, y_key = (varied + ["friction", "restitution"])[:2] if varied else ("friction", "restitution")
    if x_key == y_key:
        y_key = "restitution" if x_key != "restitution" else "friction"
    lo, hi = ranges["friction"]
    cmap = plt.get_cmap("viridis")
    final = {}
    seen = set()
    markers = {}  # aspect ratio -> marker, when the aspect ratio is not on an axis
    colours = {"train": "tab:blue", "valid": "tab:orange", "test": "tab:red"}
    for split, traj_path in dataset_paths(metadata):
        # the runout needs every frame; read one trajectory at a time
        traj = read_trajectory(traj_path)
        a = traj.attrs
        aspect = float(a["aspect_ratio"])
        marker = (
            "o" if "aspect_ratio" in (x_key, y_key) else markers.setdefault(aspect, "os^Dv<>ph*"[len(markers) % 10])
        )
        ax_p.scatter(
            float(a[x_key]),
            float(a[y_key]),
            s=22,
            color=colours[split],
            marker=marker,
            label=split if split not in seen else None,
        )
        seen.add(split)
        t, curve = runout.curve(traj)
        final[traj_path] = float(curve[-1])
        shade = 0.5 if hi == lo else (float(a["friction"]) - lo) / (hi - lo)
        ax_r.plot(t, curve, color=cmap(shade), lw=0.8, alpha=0.8)
    title = f"{metadata['name']}: cases by split"
    if len(markers) > 1:
        title += "\nmarkers: a = " + ", ".join(f"{m} {k:g}" for k, m in sorted(markers.items()))
    ax_p.set(xlabel=x_key, ylabel=y_key, title=title)
    ax_p.legend(fontsize=8)
    ax_p.grid(alpha=0.3)
    ax_r.set(xlabel="t / t*", ylabel="L* = (L - L_i) / L_i", title=f"runout, coloured by friction\n{runout.label}")
    ax_r.grid(alpha=0.3)
    norm = matplotlib.colors.Normalize(lo, hi if hi > lo else lo + 1e-9)
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax_r, label="friction mu")
    fig.tight_layout()
    save_figure(fig, path)
    return final


__all__ = ["build_dataset", "load_dataset_metadata", "plot_dataset", "DatasetError", "TrajectoryError"]
