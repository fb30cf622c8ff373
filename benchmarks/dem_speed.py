"""The builtin DEM's speed in this working tree against another commit, in one run; prints JSON.

  python benchmarks/dem_speed.py --against <commit> [--repeats 3] [--size-scales 5,3]

Both trees make the same runs, alternately (old, new, old, new, ...), each in a fresh process
(`git worktree` of --against in a scratch folder; this checkout as it stands), one thread: the runs
of the default DAG's answer job, the measured quartz column (a = 6, L_i = 0.02 m) with the side-wall
friction model at the answer (mu, e, mu_sw) = (0.89, 0.734, 0.112), packing seed 1, settled and
collapsed over 3.5 t* (what the job simulates) at each --size-scales (5: 589 grains, 3: 1,635,
2: 3,680). Kernels are loaded (or compiled) by a short run first, outside the timing.
For each size_scale: the settle's and the collapse's wall seconds, medians over --repeats, the ratio
old / new of the medians and per pair (one old and one new run next to each other, the fairest
comparison on a shared machine), and whether every run gave the same bits (sha256 of the packing's
and the collapse's positions): a kernel change that keeps them keeps every answer of the DAG.
Then the dense runout rule's mask (dem.runout.dense_mask) on every frame of the collapse, as the
GNS objective reads a rollout: milliseconds a frame, and whether every run gave the same masks.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from gns_speed import machine  # noqa: E402 - the date, machine and load the benchmarks print
from gns_train_speed import checked_out, run_in_tree  # noqa: E402 - the old commit's worktree, a run in it

WORKER = r"""
import hashlib, json, sys, time
import numpy as np
from dem.case import CollapseCase
from dem.collapse import simulate_collapse
from dem.packing import settle_column
from dem.runout import RunoutMethod
case = CollapseCase("quartz", 0.02, 6.0, 0.89, 0.734, seed=1, size_scale=float(sys.argv[1]),
                    sidewall_friction=0.112, duration_over_tstar=3.5, name="dem_speed")
warm = case.replace(size_scale=5.0, duration_over_tstar=0.05)
simulate_collapse(warm, settle_column(warm))
t0 = time.perf_counter()
packing = settle_column(case)
t1 = time.perf_counter()
trajectory = simulate_collapse(case, packing)
t2 = time.perf_counter()
dense = RunoutMethod("dense_front")  # the rule's mask on every frame, as the GNS objective reads it
masks = np.array([dense.front_mask(p, trajectory.radius) for p in trajectory.positions])
t3 = time.perf_counter()
digest = hashlib.sha256(np.ascontiguousarray(packing.positions).tobytes())
digest.update(np.ascontiguousarray(trajectory.positions).tobytes())
print(json.dumps({"grains": case.n_particles, "settle_s": t1 - t0, "collapse_s": t2 - t1,
                  "dense_mask_ms_per_frame": 1e3 * (t3 - t2) / len(masks),
                  "masks_sha256": hashlib.sha256(np.packbits(masks).tobytes()).hexdigest()[:16],
                  "steps": int(trajectory.attrs["steps"]), "sha256": digest.hexdigest()[:16]}))
"""


def summary(old: list[dict], new: list[dict]) -> dict:
    """Medians, ratios old / new and per pair, and whether all runs gave the same bits."""
    median = lambda runs, key: statistics.median(r[key] for r in runs)  # noqa: E731
    out = {"grains": new[0]["grains"], "collapse_steps": new[0]["steps"]}
    for key in ("settle_s", "collapse_s", "dense_mask_ms_per_frame"):
        name = key.removesuffix("_s").removesuffix("_ms_per_frame")
        out[f"old_{key}"], out[f"new_{key}"] = round(median(old, key), 3), round(median(new, key), 3)
        out[f"{name}_speedup"] = round(median(old, key) / median(new, key), 3)
        out[f"{name}_speedup_per_pair"] = [round(o[key] / n[key], 3) for o, n in zip(old, new)]
    out["same_bits"] = len({r["sha256"] for r in old + new}) == 1
    out["same_dense_masks"] = len({r["masks_sha256"] for r in old + new}) == 1
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--against", required=True, help="the old commit")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size-scales", default="5,3")
    args = parser.parse_args()
    started = machine()
    scales = [float(s) for s in args.size_scales.split(",")]
    runs = {s: {"old": [], "new": []} for s in scales}
    with tempfile.TemporaryDirectory() as scratch, checked_out(args.against, Path(scratch) / "old") as old_tree:
        for _ in range(args.repeats):
            for scale in scales:
                for label, tree in (("old", old_tree), ("new", ROOT)):
                    runs[scale][label].append(run_in_tree(tree, WORKER, str(scale)))
    against = subprocess.run(["git", "rev-parse", "--short", args.against], cwd=ROOT, capture_output=True, text=True)
    result = {
        "benchmark": "dem_speed",
        **started,
        "against": against.stdout.strip(),
        "size_scales": {f"{s:g}": summary(runs[s]["old"], runs[s]["new"]) for s in scales},
        "load_average_1min_at_end": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
