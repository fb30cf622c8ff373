"""GNS training and rollout speed of this working tree against another commit, in one run; prints JSON.

  python benchmarks/gns_train_speed.py --against <commit> [--repeats 3] [--train-steps 60]
                                       [--threads 2] [--dataset metadata.json]

Both trees time the same work, alternately (old, new, old, new, ...), each in a fresh process
(`git worktree` of --against in a scratch folder; this checkout as it stands):
- training: --train-steps steps of the calibrated model's GNS settings as config/config.yaml gives
  them (gns, calibration.gns_*: latent 48, M = 3, batch 2, pushforward half the steps), after 5
  warm-up steps; steps per wall second
  and the minor page faults per step;
- rollout: the no-gradient path the inverse design, the validation and the evaluation take: a test
  trajectory rolled out from its first C frames to its last; ms per GNS step and faults per step;
- batched rollout: the same, from 4 copies of its start side by side as 4 graphs of one batch, the
  shape of the GNS inverse design's rollouts (one point, S = 4 packings);
- the matrix products (aten mm, addmm, bmm; forward and backward) of as many training steps more,
  each timed where it runs: ms a step and GFLOP/s. Were everything else in a step free, the step
  would take the products' time: `products_alone_cap_over_old` is that speed over old's steps/s,
  the most any implementation of this model running these products could gain (3x is
  `threefold_reachable_with_these_products`); `products_at_large_product_rate_cap_over_old` is the
  same were the products as fast as one large square product (2048^3) is on this machine, the
  nearest a kernel of these skinny shapes (K = 48) could come to its peak;
- the weights after the timed steps, hashed: the same hash in both trees says the change kept the
  training's numbers, so its validation accuracy at equal steps is the old one by construction.
The data: --dataset, or (default) a dataset made here from one builtin-DEM collapse of the
scale_ladder column (quartz, a = 6, size_scale 5: 589 grains, frames 0.005 s apart, 4 t*), copied
under 9 parameter sets (6 train, 2 valid, 1 test), which is what the step costs depend on (grains,
edges, frames), not what they hold.
Ratios are new / old of the medians over --repeats, and per pair (one old and one new run next to
each other, the fairest comparison on a shared machine).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from gns_speed import machine  # noqa: E402 - the date, machine and load every GNS benchmark prints


def model_settings() -> dict:
    """The calibrated model's GNS settings from config/config.yaml (gns, calibration.gns_*), as the DAG
    trains them, on the CPU."""
    sys.path.insert(0, str(ROOT))
    import yaml

    from pipeline.calibrated_gns import model_gns_settings
    from pipeline.config import gns_dataset_settings, gns_datasets

    config = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    calibration = config["calibration"]
    settings = model_gns_settings(
        gns_dataset_settings(config, gns_datasets(config)[0]),
        calibration["gns_steps"],
        None,
        calibration.get("gns_learning_rate"),
        calibration["gns_latent_size"],
        calibration["gns_learning_rate_decay_steps"],
    )
    return {**settings, "device": "cpu"}


WORKER = r"""
import hashlib, json, resource, sys, time
import torch
torch.set_num_threads(int(sys.argv[3]))
from dem.trajectory import read_trajectory
from gns.dataset import read_metadata, split_paths
from gns.settings import TrainSettings
from gns.train import Trainer
from gns.rollout import rollout_trajectory
settings = TrainSettings.from_config(json.loads(sys.argv[4]))
trainer = Trainer(sys.argv[1], sys.argv[2], settings)
faults = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    trainer.train_step()
steps = int(sys.argv[5])
f0, t0 = faults(), time.perf_counter()
for _ in range(steps):
    trainer.train_step()
train_s, train_faults = time.perf_counter() - t0, faults() - f0
weights = hashlib.sha256(b"".join(p.detach().numpy().tobytes() for p in trainer.simulator.parameters())).hexdigest()
# the matrix products of the same number of steps more, each timed where it runs (forward and backward)
from torch.utils._python_dispatch import TorchDispatchMode
PRODUCTS = {torch.ops.aten.mm.default, torch.ops.aten.addmm.default, torch.ops.aten.bmm.default}
class ProductClock(TorchDispatchMode):
    seconds, flops = 0.0, 0.0
    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func not in PRODUCTS:
            return func(*args, **(kwargs or {}))
        t = time.perf_counter()
        out = func(*args, **(kwargs or {}))
        self.seconds += time.perf_counter() - t
        a, b = args[-2:] if func is not torch.ops.aten.addmm.default else args[1:3]
        self.flops += 2.0 * a.numel() * b.shape[-1]
        return out
clock = ProductClock()
with clock:
    for _ in range(steps):
        trainer.train_step()
# this machine's rate on one large product (2048^3, the shape a GEMM kernel runs nearest its peak)
square = torch.randn(2048, 2048)
torch.mm(square, square)
t0 = time.perf_counter()
for _ in range(5):
    torch.mm(square, square)
peak_gflop_per_s = 5 * 2 * 2048**3 / (time.perf_counter() - t0) / 1e9
model = trainer.averaged.eval()
dem = read_trajectory(split_paths(read_metadata(sys.argv[1]), "test")[0])
rollout_trajectory(model, dem, n_steps=2)
f0, t0 = faults(), time.perf_counter()
gns = rollout_trajectory(model, dem, on_invalid="flag")
rollout_s, rollout_faults = time.perf_counter() - t0, faults() - f0
n = int(gns.attrs["rollout_steps"])
# the inverse design's shape: one point rolled out from S = 4 packings at once, 4 graphs in one batch
from gns.rollout import context_from_trajectory, rollout
from gns.simulator import Context
one, s = context_from_trajectory(model, dem), 4
context = Context(one.particle_type.repeat(s), one.radius.repeat(s), one.parameters.repeat(s, 1),
                  one.layout.repeat(s, 1), torch.arange(s).repeat_interleave(dem.n_particles))
start = torch.as_tensor(dem.positions[: model.config.n_input_frames]).repeat(1, s, 1)
with torch.no_grad():
    rollout(model, start, context, 2, checkpoint=False, on_invalid="flag")
    f0, t0 = faults(), time.perf_counter()
    rollout(model, start, context, n, checkpoint=False, on_invalid="flag")
batch_s, batch_faults = time.perf_counter() - t0, faults() - f0
print(json.dumps({"batch4_rollout_ms_per_step": 1e3 * batch_s / n, "batch4_rollout_faults_per_step": batch_faults / n,
                  "train_steps_per_s": steps / train_s, "train_faults_per_step": train_faults / steps,
                  "product_ms_per_step": 1e3 * clock.seconds / steps,
                  "product_gflop_per_s": clock.flops / clock.seconds / 1e9,
                  "product_gflop_per_step": clock.flops / steps / 1e9, "large_product_gflop_per_s": peak_gflop_per_s,
                  "rollout_ms_per_step": 1e3 * rollout_s / n, "rollout_faults_per_step": rollout_faults / n,
                  "rollout_steps": n, "weights_sha256": weights[:16]}))
"""


def make_dataset(folder: Path) -> str:
    """One builtin-DEM collapse of the scale_ladder column at size_scale 5, as 9 cases (module docstring)."""
    sys.path.insert(0, str(ROOT))
    import yaml

    from dem.collapse import simulate_collapse
    from dem.grid import case_from_row
    from dem.packing import settle_column
    from dem.scale_ladder import case_rows
    from dem.trajectory import Trajectory, write_trajectory
    from gns.dataset import build_dataset

    spec = dict(yaml.safe_load((ROOT / "config/config.yaml").read_text())["scale_ladder"])
    spec.update(size_scales=[5], packings=1, duration_over_tstar=4, seed=1)
    case = case_from_row(case_rows(spec)[0]).replace(output_interval=0.005)
    dem = simulate_collapse(case, settle_column(case, threads=1), threads=1)
    splits, k = {"train": [], "valid": [], "test": []}, 0
    for split, n in (("train", 6), ("valid", 2), ("test", 1)):
        for j in range(n):
            attrs = dict(dem.attrs, friction=0.3 + 0.06 * k, restitution=0.3 + 0.06 * k)
            path = folder / f"{split}_{j}.h5"
            write_trajectory(path, Trajectory(dem.positions, dem.radius, dem.particle_type, attrs))
            splits[split].append(str(path))
            k += 1
    build_dataset(splits, folder / "metadata.json", "gns_train_speed")
    return str(folder / "metadata.json")


def run_worker(tree: Path, dataset: str, scratch: Path, threads: int, steps: int, settings: dict) -> dict:
    out = tempfile.mkdtemp(dir=scratch)
    return run_in_tree(tree, WORKER, dataset, out, str(threads), json.dumps(settings), str(steps))


def run_in_tree(tree: Path, script: str, *argv: str) -> dict:
    """The JSON line `python -c script *argv` prints last, run in a fresh process on the code of `tree`."""
    proc = subprocess.run(
        [sys.executable, "-c", script, *argv],
        cwd=tree,
        env=dict(os.environ, PYTHONPATH=str(tree)),
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        sys.exit(f"worker in {tree} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


@contextlib.contextmanager
def checked_out(commit: str, folder: Path) -> Iterator[Path]:
    """A `git worktree` of `commit` at `folder` for the block, removed afterwards."""
    add = ["git", "worktree", "add", "--detach", str(folder), commit]
    subprocess.run(add, cwd=ROOT, check=True, capture_output=True)
    try:
        yield folder
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(folder)], cwd=ROOT, check=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--against", required=True, help="the old commit")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--train-steps", type=int, default=60)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--dataset", default=None)
    args = parser.parse_args()
    started = machine()
    with tempfile.TemporaryDirectory() as scratch_name, checked_out(args.against, Path(scratch_name) / "old") as old:
        scratch, old_tree = Path(scratch_name), old
        dataset = args.dataset or make_dataset(scratch)
        settings, runs = model_settings(), {"old": [], "new": []}
        for _ in range(args.repeats):
            for label, tree in (("old", old_tree), ("new", ROOT)):
                runs[label].append(run_worker(tree, dataset, scratch, args.threads, args.train_steps, settings))
    median = lambda label, key: statistics.median(r[key] for r in runs[label])  # noqa: E731
    keys = (
        "train_steps_per_s",
        "train_faults_per_step",
        "rollout_ms_per_step",
        "rollout_faults_per_step",
        "batch4_rollout_ms_per_step",
        "batch4_rollout_faults_per_step",
        "product_ms_per_step",
        "product_gflop_per_s",
        "product_gflop_per_step",
        "large_product_gflop_per_s",
    )
    # were everything but the products free, new would train 1000 / product_ms steps/s
    product_cap = 1e3 / median("new", "product_ms_per_step") / median("old", "train_steps_per_s")
    # and were the products as fast as one large product is here
    flop_cap = median("new", "large_product_gflop_per_s") / median("new", "product_gflop_per_step")
    flop_cap /= median("old", "train_steps_per_s")
    result = {
        "benchmark": "gns_train_speed",
        **started,
        "against": subprocess.run(
            ["git", "rev-parse", "--short", args.against], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip(),
        "threads": args.threads,
        "train_steps": args.train_steps,
        "settings": settings,
        "old": {k: round(median("old", k), 3) for k in keys},
        "new": {k: round(median("new", k), 3) for k in keys},
        "train_speedup": round(median("new", "train_steps_per_s") / median("old", "train_steps_per_s"), 3),
        "rollout_speedup": round(median("old", "rollout_ms_per_step") / median("new", "rollout_ms_per_step"), 3),
        "batch4_rollout_speedup": round(
            median("old", "batch4_rollout_ms_per_step") / median("new", "batch4_rollout_ms_per_step"), 3
        ),
        "train_speedup_per_pair": [
            round(n["train_steps_per_s"] / o["train_steps_per_s"], 3) for o, n in zip(runs["old"], runs["new"])
        ],
        "rollout_speedup_per_pair": [
            round(o["rollout_ms_per_step"] / n["rollout_ms_per_step"], 3) for o, n in zip(runs["old"], runs["new"])
        ],
        "products_alone_cap_over_old": round(product_cap, 3),
        "threefold_reachable_with_these_products": product_cap >= 3.0,
        "products_at_large_product_rate_cap_over_old": round(flop_cap, 3),
        "same_weights_after_training": len({r["weights_sha256"] for r in runs["old"] + runs["new"]}) == 1,
        "runs": runs,
        "load_average_1min_at_end": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
