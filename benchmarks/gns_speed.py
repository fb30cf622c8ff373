"""GNS speed against the builtin DEM, measured in one run; prints JSON. Two modes.

One dataset case:

  python benchmarks/gns_speed.py [--dataset results/datasets/quartz_multiple/metadata.json]
                                 [--model results/gns/quartz_multiple/train/model_best.pt]
                                 [--case PATH] [--threads 1] [--train-steps 40]

- training steps/s: `--train-steps` steps of the model's own training settings on the dataset
- GNS rollout: the test case (default: the dataset's largest test case) rolled out from its first
  C DEM frames to its last frame, no gradient
- DEM, builtin engine, same case, same thread count: the collapse from the same settled packing
  (frame 0), and the settling of that packing, each timed (numba kernels loaded before timing)
Speed-ups, DEM over GNS:
  speedup_collapse               DEM collapse / GNS rollout
  speedup_collapse_given_start   DEM collapse / (GNS rollout + the DEM's share of the first C
                                 frames the rollout starts from): the strictest; `meets_target`
  speedup_settle_and_collapse    (DEM settle + collapse) / GNS rollout: a new parameter set in the
                                 inverse design, where every GNS rollout reuses one start but the
                                 DEM has to settle the column again (the packing depends on mu, e)
Target: GNS rollout at least 2x faster than the builtin DEM.

Across grain sizes: how the speed-up grows as the grains get finer.

  python benchmarks/gns_speed.py --size-scales 5,4,3,2 [--model PATH] [--duration 4]
                                 [--config config/config.yaml] [--threads 1]

- The column of --config's scale_ladder section (by default the measured quartz column: a = 6,
  L_i = 0.02 m, (mu, e) = (0.39, 0.54), 4 t*; dem/scale_ladder.py builds it), packing seed
  scale_ladder.seed, at each size_scale, with frames every dt_frame of the GNS: the checkpoint's
  with --model, else the output_interval of the config's GNS dataset (the first of gns.datasets:
  quartz_multiple, 0.005 s, 89 frames over 4 t*).
- DEM, per size_scale: the column settled, then collapsed from that packing, each timed.
- GNS, per size_scale, timed twice over the same physical duration and frames:
  rollout     free rollout from the DEM run's first C frames to its last frame
              (gns.rollout.rollout_trajectory, as in the one-case mode); its speed-ups are none
              where it stopped early (left the box)
  along_dem   the same steps, each from the DEM's own previous C frames instead of the model's:
              the cost of a rollout that follows the DEM, whatever the weights
  The model: --model, a trained checkpoint (e.g. results/gns/quartz_multiple/train/model_best.pt,
  trained at size_scale 5), its connectivity radius and mean grain radius carried over to each
  scale's grains (below), its weights and normalisation as trained. Without --model: the
  architecture of --config's gns section with gns.per_dataset of its dataset (latent size, message
  passing steps, MLP layers, C, connectivity radius) with seeded random weights and normalisation
  statistics from the DEM run itself (gns.dataset.build_dataset, as if trained at that scale). A
  step's cost does not depend on the weights, only on grains and edges, but a random model's own
  rollout does not follow the DEM (at size_scale 5 it leaves the box at step 66 of 83, its graph
  thinning from ~9.5 to 6 edges per grain): then read the along_dem times.
- Connectivity radius: the config gives it in mean grain diameters of the dataset
  (gns.connectivity_radius: 2.0, ~10 edges per grain in the settled column);
  gns.settings.simulator_config turns it into metres with the dataset's mean diameter, and a
  checkpoint stores the metres. At every size_scale the radius is that many diameters of that
  scale's grains, so each grain has about as many neighbours as in training and the graph grows as
  the grains, ~s^-2 (a radius fixed in metres would give each grain (5/s)^2 times the edges at
  size_scale s as at the training's 5). Edges per node are reported, of the DEM frames and of the
  rollout.
- Per size_scale: grains, DEM settle and collapse steps and times (wall and CPU s), the GNS's
  rollout and along_dem times, edges per node, speed-ups DEM over GNS (collapse / GNS and
  (settle + collapse) / GNS, for each GNS timing), and the largest distance a grain moves between
  two frames in grain diameters (the GNS steps a frame at a time: with the same frame interval,
  finer grains move more diameters a step than in training).
- Exponents: the log-log slopes of DEM and GNS cost against size_scale, next to the expected -3.5
  (grains ~s^-2 times time steps ~s^-1.5: t_c ~ sqrt(m / k_n) with k_n fixed) and -2 (grains; the
  number of GNS steps does not change). A GNS step has a part that does not grow with the grains
  (operator launches, Python), so at coarse grains its slope is shallower than -2.

Times are wall seconds and, since the box is shared, also CPU seconds of this process (the wall time
on an idle core).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

EXPECTED_EXPONENT = {"dem": -3.5, "gns": -2.0}  # cost ~ size_scale^exponent (docs/experiments/grain-size.md)


def timed(function):
    """(result, wall s, CPU s of this process) of function()."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def ratio(numerator: float, denominator: float) -> float:
    return round(numerator / denominator, 3)


def load_kernels(case, packing, threads: int) -> None:
    """Run the DEM's numba kernels once (two frames of collapse from `packing`) so no timing loads them."""
    from dem.collapse import simulate_collapse

    short = case.replace(duration_over_tstar=2 * case.frame_interval / case.t_star)
    simulate_collapse(short, packing=packing, threads=threads)


def time_rollout(simulator, dem):
    """GNS rollout of `dem`'s case from its first C frames to its last frame, after a 2-step warm-up:
    (rollout trajectory, wall s, CPU s)."""
    from gns.rollout import rollout_trajectory

    rollout_trajectory(simulator, dem, n_steps=2)  # warm-up (allocations, first graph)
    return timed(lambda: rollout_trajectory(simulator, dem, on_invalid="flag"))


def time_steps_along(simulator, dem):
    """The GNS steps of a rollout of `dem`'s case, each from the DEM's own previous C frames instead of
    the model's (the graphs of a rollout that follows the DEM, whatever the weights), no gradient,
    after a 2-step warm-up: (wall s, CPU s)."""
    import torch

    from gns.rollout import context_from_trajectory

    c = simulator.config.n_input_frames
    context = context_from_trajectory(simulator, dem)
    frames = torch.as_tensor(dem.positions, dtype=torch.float32)  # [T, N, 2]

    def steps(last: int) -> None:
        with torch.no_grad():
            for k in range(c, last):
                simulator.predict_positions(frames[k - c : k].transpose(0, 1), context)

    steps(c + 2)
    _, wall, cpu = timed(lambda: steps(dem.n_frames))
    return wall, cpu


def edges_per_node(positions: np.ndarray, connectivity_radius_m: float) -> float:
    """Mean edges per grain of the GNS's radius graph on positions [N, 2] (m)."""
    import torch

    from gns.graph import graph_summary, radius_graph

    senders, _ = radius_graph(torch.as_tensor(positions), connectivity_radius_m)
    return round(graph_summary(len(positions), senders)["edges_per_node"], 2)


def machine() -> dict:
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "load_average_1min_at_start": round(os.getloadavg()[0], 2),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="results/datasets/quartz_multiple/metadata.json")
    parser.add_argument(
        "--model",
        default=None,
        help="one case: default results/gns/<dataset name>/train/model_best.pt; --size-scales: default random weights",
    )
    parser.add_argument("--case", default=None, help="DEM trajectory to time (default: largest test case)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--train-steps", type=int, default=40)
    parser.add_argument("--size-scales", default=None, help="e.g. 5,4,3,2: time the scale_ladder column at each")
    parser.add_argument("--config", default=str(ROOT / "config/config.yaml"), help="--size-scales: column and GNS")
    parser.add_argument("--duration", type=float, default=None, help="--size-scales: t* of collapse (default 4)")
    args = parser.parse_args()
    os.environ["NUMBA_NUM_THREADS"] = str(args.threads)  # before numba loads: the DEM gets the same cores
    import torch

    torch.set_num_threads(args.threads)
    info = machine()
    result = size_scales_speed(args) if args.size_scales else case_speed(args)
    result = {**info, **result, "load_average_1min_at_end": round(os.getloadavg()[0], 2)}
    print(json.dumps(result, indent=1))


def case_speed(args) -> dict:
    """Training, rollout and DEM times on one dataset case (the first mode of the docstring)."""
    import torch

    from dem.collapse import simulate_collapse
    from dem.packing import settle_column
    from dem.runout_study import case_of
    from dem.trajectory import Trajectory, read_attrs, read_trajectory
    from gns.dataset import read_metadata
    from gns.settings import TrainSettings
    from gns.simulator import load_simulator
    from gns.train import Trainer

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
    gns, gns_wall, gns_cpu = time_rollout(simulator, dem)

    case = case_of(dem)
    packing = Trajectory(dem.positions[:1], dem.radius, dem.particle_type, dict(dem.attrs))
    load_kernels(case, packing, args.threads)
    _, settle_wall, settle_cpu = timed(lambda: settle_column(case, threads=args.threads))
    _, dem_wall, dem_cpu = timed(lambda: simulate_collapse(case, packing=packing, threads=args.threads))

    steps = int(gns.attrs["rollout_steps"])
    c = simulator.config.n_input_frames
    start_share = (c - 1) / (dem.n_frames - 1)  # of the collapse: the frames the GNS starts from
    result = {
        "benchmark": "gns_speed",
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
    return result


# -- across grain sizes ------------------------------------------------------------------------------
def scaled_model(simulator, diameter: float):
    """The trained `simulator` at grains of mean diameter `diameter` (m): its connectivity radius and
    mean grain radius, stored in metres, carried over in proportion (the same number of diameters);
    weights and normalisation as trained."""
    from gns.simulator import LearnedSimulator

    c = simulator.config
    factor = diameter / (2.0 * c.mean_radius)
    config = dataclasses.replace(
        c, connectivity_radius_m=c.connectivity_radius_m * factor, mean_radius=c.mean_radius * factor
    )
    scaled = LearnedSimulator(config)
    scaled.load_state_dict(simulator.state_dict())
    return scaled.eval()


def random_model(dem, settings, scratch: str):
    """The GNS of `settings`' architecture with seeded random weights, its statistics and lengths from
    the DEM run `dem` (a one-trajectory dataset, as if trained at its scale)."""
    import torch

    from dem.trajectory import write_trajectory
    from gns.dataset import build_dataset
    from gns.settings import simulator_config
    from gns.simulator import LearnedSimulator

    path = write_trajectory(Path(scratch) / "dem.h5", dem)
    metadata = build_dataset({"train": [str(path)]}, Path(scratch) / "metadata.json", "gns_speed")
    torch.manual_seed(settings.seed)
    return LearnedSimulator(simulator_config(metadata, settings)).eval()


def slope(scales, costs) -> float | None:
    """Log-log slope of cost against size_scale (None under two scales)."""
    if len(scales) < 2:
        return None
    return round(float(np.polyfit(np.log(scales), np.log(costs), 1)[0]), 3)


def size_scales_speed(args) -> dict:
    """DEM settle and collapse against a GNS rollout of the same column at each size_scale."""
    import yaml

    from dem.collapse import simulate_collapse
    from dem.grid import case_from_row
    from dem.packing import settle_column
    from dem.scale_ladder import case_rows
    from gns.settings import TrainSettings
    from gns.simulator import load_simulator
    from pipeline.config import gns_dataset_settings, validate_config

    config = validate_config(
        yaml.safe_load(Path(args.config).read_text()), ROOT / "workflow/schemas/config.schema.yaml"
    )
    scales = sorted({float(s) for s in args.size_scales.split(",")}, reverse=True)  # coarsest first
    spec = dict(config["scale_ladder"], size_scales=scales, packings=1)
    if args.duration is not None:
        spec["duration_over_tstar"] = args.duration
    gns_dataset = (config["gns"].get("datasets") or sorted(config["datasets"]))[0]
    if args.model:
        trained = load_simulator(args.model)
        dt_frame, model = trained.config.dt_frame, str(args.model)
        settings = None
    else:
        settings = TrainSettings.from_config({**gns_dataset_settings(config, gns_dataset), "device": "cpu"})
        dt_frame = config["datasets"][gns_dataset].get("output_interval")  # None: t* / 25
        model = f"random weights, the architecture of {Path(args.config).name} gns (dataset {gns_dataset})"
    cases = [case_from_row(row).replace(output_interval=dt_frame) for row in case_rows(spec)]

    packing = settle_column(cases[0], threads=args.threads)  # loads the settle's kernels
    load_kernels(cases[0], packing, args.threads)
    rows = []
    for case in cases:
        packing, settle_wall, settle_cpu = timed(functools.partial(settle_column, case, threads=args.threads))
        dem, dem_wall, dem_cpu = timed(functools.partial(simulate_collapse, case, packing, threads=args.threads))
        diameter = float(np.mean(2.0 * dem.radius))
        with tempfile.TemporaryDirectory() as scratch:
            simulator = scaled_model(trained, diameter) if args.model else random_model(dem, settings, scratch)
        gns, gns_wall, gns_cpu = time_rollout(simulator, dem)
        along_wall, along_cpu = time_steps_along(simulator, dem)
        c, radius_m = simulator.config.n_input_frames, simulator.config.connectivity_radius_m
        steps, valid = int(gns.attrs["rollout_steps"]), bool(gns.attrs["rollout_valid"])
        moved = np.linalg.norm(np.diff(dem.positions.astype(np.float64), axis=0), axis=2)
        dem_s = {"collapse": dem_wall, "settle_and_collapse": settle_wall + dem_wall}
        dem_cpu_s = {"collapse": dem_cpu, "settle_and_collapse": settle_cpu + dem_cpu}
        row = {
            "size_scale": case.size_scale,
            "n_particles": dem.n_particles,
            "grains_across": round(case.grains_across, 2),
            "mean_diameter_m": diameter,
            "frames": dem.n_frames,
            "dem_settle_steps": int(packing.attrs["settle_steps"]),
            "dem_collapse_steps": int(dem.attrs["steps"]),
            "dem_settle_s": round(settle_wall, 3),
            "dem_settle_cpu_s": round(settle_cpu, 3),
            "dem_collapse_s": round(dem_wall, 3),
            "dem_collapse_cpu_s": round(dem_cpu, 3),
            "dem_max_move_per_frame_diameters": round(float(moved.max()) / diameter, 2),
            "gns_connectivity_radius_m": radius_m,
            "gns_connectivity_radius_diameters": round(radius_m / diameter, 3),
            "gns_steps": dem.n_frames - c,
            "gns_rollout_steps_done": steps,
            "gns_rollout_valid": valid,
            "gns_rollout_problem": gns.attrs["rollout_problem"] or None,
            "gns_rollout_s": round(gns_wall, 3),
            "gns_rollout_cpu_s": round(gns_cpu, 3),
            "gns_ms_per_step": round(1e3 * gns_wall / max(steps, 1), 2),
            "gns_along_dem_s": round(along_wall, 3),
            "gns_along_dem_cpu_s": round(along_cpu, 3),
            "edges_per_node": {
                "dem_start": edges_per_node(dem.positions[c - 1], radius_m),
                "dem_mean": round(float(np.mean([edges_per_node(x, radius_m) for x in dem.positions[c - 1 :]])), 2),
                "dem_end": edges_per_node(dem.positions[-1], radius_m),
                "gns_rollout_mean": round(float(np.mean([edges_per_node(x, radius_m) for x in gns.positions])), 2),
                "gns_rollout_end": edges_per_node(gns.positions[-1], radius_m),
            },
        }
        for name in dem_s:  # DEM over GNS; none from a rollout that stopped early
            row[f"speedup_{name}"] = ratio(dem_s[name], gns_wall) if valid else None
            row[f"speedup_{name}_cpu"] = ratio(dem_cpu_s[name], gns_cpu) if valid else None
            row[f"speedup_{name}_along_dem"] = ratio(dem_s[name], along_wall)
        rows.append(row)
        print(f"size_scale {case.size_scale:g}: done", file=sys.stderr, flush=True)

    s = [row["size_scale"] for row in rows]
    valid = all(row["gns_rollout_valid"] for row in rows)
    exponents = {
        name: {
            "wall": slope(s, [sum(row[f"{k}_s"] for k in keys) for row in rows]),
            "cpu": slope(s, [sum(row[f"{k}_cpu_s"] for k in keys) for row in rows]),
            "expected": EXPECTED_EXPONENT[name.split("_")[0]],
        }
        for name, keys in (
            ("dem_settle_and_collapse", ("dem_settle", "dem_collapse")),
            ("dem_collapse", ("dem_collapse",)),
            ("gns_rollout", ("gns_rollout",)),
            ("gns_along_dem", ("gns_along_dem",)),
        )
    }
    if not valid:
        exponents["gns_rollout"] = None  # a rollout that stopped early is not the cost of the whole one
    c = simulator.config
    return {
        "benchmark": "gns_speed_size_scales",
        "threads": args.threads,
        "case": {k: spec[k] for k in ("material", "L_i", "aspect_ratio", "friction", "restitution", "seed")},
        "duration_over_tstar": spec["duration_over_tstar"],
        "dt_frame_s": dt_frame,
        "model": model,
        "weights_note": None
        if args.model
        else (
            "random weights: a step's cost depends on the grains and the edges of its graph, not on the weights, "
            "but a random model's own rollout does not follow the DEM (it leaves the box, its graph thins): "
            "read the along_dem times"
        ),
        "gns_timing": {
            "rollout": "free rollout from the DEM run's first C frames to its last (gns.rollout.rollout_trajectory); "
            "speed-ups none where it stopped early",
            "along_dem": "the same steps, each from the DEM's own previous C frames: a rollout that follows the DEM",
        },
        "model_size": {
            "latent_size": c.latent_size,
            "mlp_hidden_layers": c.mlp_hidden_layers,
            "n_message_passing": c.n_message_passing,
            "n_input_frames_C": c.n_input_frames,
            "connectivity_radius_diameters": rows[-1]["gns_connectivity_radius_diameters"],
        },
        "connectivity_radius": "in mean grain diameters of each size_scale's grains (metres shrink with the grains)",
        "by_size_scale": rows,
        "exponents": exponents,
    }


if __name__ == "__main__":
    main()
