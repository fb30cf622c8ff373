"""GNS speed against the builtin DEM, measured in one run; prints JSON.

  python benchmarks/gns_speed.py [--dataset results/datasets/quartz_multiple/metadata.json]
                                 [--model results/gns/quartz_multiple/train/model_best.pt]
                                 [--case PATH] [--threads 1] [--train-steps 40]

- training steps/s: `--train-steps` steps of the model's own training settings on the dataset
- GNS rollout: the test case (default: the dataset's largest test case) rolled out from its first
  C DEM frames to its last frame, no gradient
- DEM, builtin engine, same case, same thread count: the collapse from the same settled packing
  (frame 0), and the settling of that packing, each timed (numba kernels loaded before timing)
Times are wall seconds and, since the box is shared, also CPU seconds of this process (the
wall time on an idle core). Speed-ups, DEM over GNS:
  speedup_collapse               DEM collapse / GNS rollout
  speedup_collapse_given_start   DEM collapse / (GNS rollout + the DEM's share of the first C
                                 frames the rollout starts from): the strictest; `meets_target`
  speedup_settle_and_collapse    (DEM settle + collapse) / GNS rollout: a new parameter set in the
                                 inverse design, where every GNS rollout reuses one start but the
                                 DEM has to settle the column again (the packing depends on mu, e)
Target (issue 5): GNS rollout at least 2x faster than the builtin DEM.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def timed(function):
    """(result, wall s, CPU s of this process) of function()."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="results/datasets/quartz_multiple/metadata.json")
    parser.add_argument("--model", default=None, help="default results/gns/<dataset name>/train/model_best.pt")
    parser.add_argument("--case", default=None, help="DEM trajectory to time (default: largest test case)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--train-steps", type=int, default=40)
    args = parser.parse_args()
    os.environ["NUMBA_NUM_THREADS"] = str(args.threads)  # before numba loads: the DEM gets the same cores
    import torch

    from dem.collapse import simulate_collapse
    from dem.packing import settle_column
    from dem.trajectory import Trajectory, read_attrs, read_trajectory
    from gns.data import read_metadata
    from gns.rollout import rollout_trajectory
    from gns.settings import TrainSettings
    from gns.simulator import load_simulator
    from gns.train import Trainer

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
        trainer.train_step()  # warm-up (allocations, first graph)
        _, train_wall, train_cpu = timed(lambda: [trainer.train_step() for _ in range(args.train_steps)])

    simulator = load_simulator(model_path, metadata)
    dem = read_trajectory(case_path)
    rollout_trajectory(simulator, dem, n_steps=2)  # warm-up
    gns, gns_wall, gns_cpu = timed(lambda: rollout_trajectory(simulator, dem, on_invalid="flag"))

    from dem.runout_study import case_of

    case = case_of(dem)
    packing = Trajectory(dem.positions[:1], dem.radius, dem.particle_type, dict(dem.attrs))
    simulate_collapse(
        case.replace(duration_over_tstar=2 * case.frame_interval / case.t_star), packing=packing
    )  # load kernels
    _, settle_wall, settle_cpu = timed(lambda: settle_column(case))
    _, dem_wall, dem_cpu = timed(lambda: simulate_collapse(case, packing=packing))

    steps = int(gns.attrs["rollout_steps"])
    c = simulator.config.n_input_frames
    start_share = (c - 1) / (dem.n_frames - 1)  # of the collapse: the frames the GNS starts from
    ratio = lambda dem_s, gns_s: round(dem_s / gns_s, 3)  # noqa: E731
    result = {
        "dataset": metadata["name"],
        "model": str(model_path),
        "case": str(case_path),
        "threads": args.threads,
        "grains": dem.n_particles,
        "frames": dem.n_frames,
        "dt_frame_s": float(dem.attrs["dt_frame"]),
        "gns_input_frames_C": c,
        "gns_steps": steps,
        "gns_rollout_valid": bool(gns.attrs["rollout_valid"]),
        "model_size": {
            "latent_size": settings.latent_size,
            "mlp_hidden_layers": settings.mlp_hidden_layers,
            "n_message_passing": settings.n_message_passing,
            "connectivity_radius_diameters": settings.connectivity_radius,
        },
        "training_batch_size": settings.batch_size,
        "training_steps_per_s": round(args.train_steps / train_wall, 3),
        "training_steps_per_cpu_s": round(args.train_steps / train_cpu, 3),
        "gns_rollout_s": round(gns_wall, 3),
        "gns_rollout_cpu_s": round(gns_cpu, 3),
        "gns_ms_per_step": round(1e3 * gns_wall / max(steps, 1), 2),
        "gns_cpu_ms_per_step": round(1e3 * gns_cpu / max(steps, 1), 2),
        "dem_builtin_collapse_s": round(dem_wall, 3),
        "dem_builtin_collapse_cpu_s": round(dem_cpu, 3),
        "dem_builtin_settle_s": round(settle_wall, 3),
        "dem_builtin_settle_cpu_s": round(settle_cpu, 3),
        "dem_time_steps": int(round(dem.attrs["t_star"] * case.duration_over_tstar / case.time_step)),
        "dem_start_frames_s": round(start_share * dem_wall, 3),
        "speedup_collapse": ratio(dem_wall, gns_wall),
        "speedup_collapse_cpu": ratio(dem_cpu, gns_cpu),
        "speedup_collapse_given_start": ratio(dem_wall, gns_wall + start_share * dem_wall),
        "speedup_collapse_given_start_cpu": ratio(dem_cpu, gns_cpu + start_share * dem_cpu),
        "speedup_settle_and_collapse": ratio(settle_wall + dem_wall, gns_wall),
        "target_speedup": 2.0,
    }
    result["meets_target"] = result["speedup_collapse_given_start"] >= 2.0
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
