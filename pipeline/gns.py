"""The GNS stage: train a graph-network simulator on one dataset, roll it out on each test case,
score the rollouts against the DEM (the report section that reads them: pipeline/gns_section.py).

The methods live in gns/ (training, rollout, scoring); here is what one Snakemake job does with
the pipeline's files.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

from dem.atomic import StrPath
from dem.runout import RunoutMethod
from dem.trajectory import Trajectory, read_trajectory, write_trajectory
from gns.evaluate import evaluate_rollouts

log = logging.getLogger(__name__)


def train(
    metadata_path: StrPath,
    out_dir: StrPath,
    settings: dict | None,
    runout: RunoutMethod | dict | str | None,
    threads: int | None = None,
) -> dict:
    """Train (or resume training) the GNS of the dataset at `metadata_path` with the config's `gns`
    settings (gns.settings.TrainSettings); outputs in `out_dir` (model_best.pt, metrics.csv,
    loss_curve.png, checkpoint_last.pt). A checkpoint made with other settings or data is moved
    aside and training starts afresh. runout: how the validation runout MSE reads L*. threads:
    torch threads (None: torch's default). Returns gns.train.train's result."""
    import torch

    from gns.settings import TrainSettings
    from gns.train import train as train_gns

    if threads:
        torch.set_num_threads(threads)
    settings = TrainSettings.from_config(settings)
    log.info("settings %s", settings)
    return train_gns(metadata_path, out_dir, settings, restart_on_mismatch=True, runout=runout)


def rollout(
    model_path: StrPath,
    dem_path: StrPath,
    out_path: StrPath,
    metadata_path: StrPath | None = None,
    threads: int | None = None,
) -> Trajectory:
    """Roll out the case of the DEM trajectory `dem_path` with the model at `model_path` from its
    first C frames to its last frame; write it (engine "gns") to `out_path`. A rollout that fails
    is written up to the failing step, with rollout_valid = 0 and the reason in rollout_problem.
    threads: torch threads (None: leave torch's setting)."""
    import torch

    from gns.dataset import read_metadata
    from gns.rollout import rollout_trajectory
    from gns.simulator import load_simulator

    if threads:
        torch.set_num_threads(threads)
    metadata = read_metadata(metadata_path) if metadata_path else None
    simulator = load_simulator(model_path, metadata)
    dem = read_trajectory(dem_path)
    gns = rollout_trajectory(simulator, dem, on_invalid="flag", model_name=Path(model_path).name)
    if not gns.attrs["rollout_valid"]:
        log.warning("rollout of %s failed: %s", dem_path, gns.attrs["rollout_problem"])
    log.info("rolled out %s: %d steps in %.2f s", dem_path, gns.attrs["rollout_steps"], gns.attrs["wall_time_s"])
    write_trajectory(out_path, gns)
    return gns


def evaluate(dem_paths: Sequence, gns_paths: Sequence, out_dir: StrPath, runout: RunoutMethod | dict | str) -> dict:
    """Score the GNS rollouts `gns_paths` against the DEM trajectories `dem_paths` (same order) with
    gns.evaluate.evaluate_rollouts: metrics.csv, summary.json, runout_curves.png, snapshots/ in
    `out_dir`. Returns the summary."""
    return evaluate_rollouts(list(zip(dem_paths, gns_paths)), out_dir, runout)
