"""GNS speed against the builtin DEM, measured in one run; prints JSON.

  python benchmarks/gns_speed.py [--dataset results/datasets/quartz_friction/metadata.json]
                                 [--model results/gns/quartz_friction/train/model_best.pt]
                                 [--case PATH] [--threads 1] [--train-steps 20]

- training steps/s: `--train-steps` steps of the model's own training settings on the dataset
- GNS rollout: the test case (default: the dataset's first test case, the biggest if several)
  rolled out from its first C frames to its last frame, no gradient
- DEM: the same case run by the builtin engine from the same settled packing (frame 0), so
  neither side pays for settling
Target (issue 5): GNS rollout at least 2x faster than the builtin DEM.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dem.case import CollapseCase, Material  # noqa: E402
from dem.collapse import simulate_collapse  # noqa: E402
from dem.trajectory import Trajectory, read_attrs, read_trajectory  # noqa: E402
from gns.data import read_metadata  # noqa: E402
from gns.rollout import rollout_trajectory  # noqa: E402
from gns.simulator import load_simulator  # noqa: E402
from gns.train import TrainSettings, Trainer  # noqa: E402


def case_of(trajectory: Trajectory) -> CollapseCase:
    """The CollapseCase a builtin trajectory was run for, from its attributes."""
    a = trajectory.attrs
    fields = {f.name: a[f.name] for f in dataclasses.fields(CollapseCase) if f.name in a and f.name != "material"}
    material = Material(a["material"], a["material_diameter"], a["material_density"], a["material_solid_fraction"])
    return CollapseCase(material=material, **fields)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="results/datasets/quartz_friction/metadata.json")
    parser.add_argument("--model", default=None, help="default results/gns/<dataset name>/train/model_best.pt")
    parser.add_argument("--case", default=None, help="DEM trajectory to time (default: largest test case)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--train-steps", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    metadata = read_metadata(args.dataset)
    model_path = Path(args.model or f"results/gns/{metadata['name']}/train/model_best.pt")
    if not model_path.exists():
        sys.exit(f"{model_path}: no trained model; run the workflow (bash run.sh main) or pass --model")
    case_path = args.case or max(metadata["splits"]["test"], key=lambda p: read_attrs(p)["H_i"] * read_attrs(p)["L_i"])
    payload = torch.load(model_path, map_location="cpu", weights_only=False)
    settings = TrainSettings.from_config(dict(payload.get("settings") or {}, device="cpu"))

    with tempfile.TemporaryDirectory() as scratch:
        trainer = Trainer(args.dataset, scratch, settings)
        trainer.train_step()                                   # warm-up (allocations, first graph)
        start = time.perf_counter()
        for _ in range(args.train_steps):
            trainer.train_step()
        train_rate = args.train_steps / (time.perf_counter() - start)

    simulator = load_simulator(model_path, metadata)
    dem = read_trajectory(case_path)
    rollout_trajectory(simulator, dem, n_steps=2)              # warm-up
    gns = rollout_trajectory(simulator, dem, on_invalid="flag")
    gns_seconds = float(gns.attrs["wall_time_s"])

    case = case_of(dem)
    packing = Trajectory(dem.positions[:1], dem.radius, dem.particle_type, dict(dem.attrs))
    start = time.perf_counter()
    simulate_collapse(case, packing=packing)
    dem_seconds = time.perf_counter() - start

    steps = int(gns.attrs["rollout_steps"])
    print(json.dumps({
        "dataset": metadata["name"], "model": str(model_path), "case": str(case_path), "threads": args.threads,
        "grains": dem.n_particles, "frames": dem.n_frames, "gns_steps": steps,
        "gns_rollout_valid": bool(gns.attrs["rollout_valid"]),
        "model_size": {"latent_size": settings.latent_size, "n_message_passing": settings.n_message_passing,
                       "connectivity_radius_diameters": settings.connectivity_radius},
        "training_steps_per_s": round(train_rate, 3), "training_batch_size": settings.batch_size,
        "gns_rollout_s": round(gns_seconds, 3), "gns_ms_per_step": round(1e3 * gns_seconds / max(steps, 1), 2),
        "dem_builtin_s": round(dem_seconds, 3), "dem_time_steps": int(round(dem.attrs["t_star"] * case.duration_over_tstar / case.time_step)),
        "speedup_gns_over_dem": round(dem_seconds / gns_seconds, 3), "target_speedup": 2.0,
        "meets_target": dem_seconds / gns_seconds >= 2.0}, indent=1))


if __name__ == "__main__":
    main()
