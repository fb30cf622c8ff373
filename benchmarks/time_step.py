"""How the collapse's answer depends on the time step, against the packing scatter; prints JSON.

The measured quartz column (a = 6, L_i = 0.02 m) at (mu, e) = (0.39, 0.54), at each --size-scales
(default 3: 1,635 grains), on --packings packings (seeds 0, 1, ...), each settled and collapsed over
4 t* at every dt / contact time of --steps (default 1/50, the default, and 1/25; the settle's step
follows the collapse's, 2.5x), so the differences are paired by seed (the same poured lattice; the
settle and the collapse then draw their own chaos). Per size_scale and step: L* (the default runout reading) at
t/t* = 1, 2, 3.5 and 4 and the final deposit height over H_i, as mean and packing scatter; per coarser
step, the paired difference to the finest (mean, its standard error over packings, and that mean
over the one-packing scatter of the finest step); the settle's and the collapse's wall seconds and
the speed-up of the two together. A
step whose differences lie well inside the packing scatter changes no answer the project gives
(every answer is a mean over packings); the known answers at each step (restitution, sliding to
rolling) are tests/test_physics.py's.

    python benchmarks/time_step.py [--size-scales 3] [--packings 6] [--steps 0.02,0.04] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dem.case import CollapseCase  # noqa: E402
from dem.runout import RunoutMethod  # noqa: E402
from dem.scale_ladder import READ_AT, read_run, scatter  # noqa: E402


def column(size_scale: float, seed: int, dt_over_contact_time: float = 1 / 50) -> CollapseCase:
    return CollapseCase(
        "quartz", 0.02, 6.0, 0.39, 0.54, seed=seed, size_scale=size_scale, dt_over_contact_time=dt_over_contact_time
    )


def one_packing(size_scale: float, seed: int, steps: list[float]) -> dict:
    """{step: read_run(...)}: packing `seed` settled and collapsed at every step (one thread); the
    settle's own step follows the collapse's (dem.packing.settle_time_step)."""
    from dem.collapse import simulate_collapse
    from dem.packing import settle_column

    runs = {}
    for step in steps:
        case = column(size_scale, seed, step)
        started = time.perf_counter()
        packing = settle_column(case)
        runs[step] = read_run(simulate_collapse(case, packing), RunoutMethod(), time.perf_counter() - started)
    print(f"size_scale {size_scale:g} seed {seed}: done", file=sys.stderr, flush=True)
    return runs


def readings(run) -> dict:
    """{name: value} of one run: L* at READ_AT points and at the last frame, final height / H_i."""
    out = {f"L*({x:g})": float(np.interp(x, run.t_over_tstar, run.runout)) for x in READ_AT}
    out["L*(final)"] = float(run.runout[-1])
    out["height/H_i(final)"] = float(run.final_height_over_H_i)
    return out


def compare(per_packing: list[dict], steps: list[float]) -> dict:
    """Per step the readings' scatter over packings and the paired differences to the finest step."""
    finest = min(steps)
    values = {step: [readings(runs[step]) for runs in per_packing] for step in steps}
    names = list(values[finest][0])
    out = {}
    for step in sorted(steps):
        entry = {
            "dt_over_contact_time": step,
            "readings": {name: scatter([v[name] for v in values[step]]) for name in names},
            "settle_s": scatter([runs[step].settle_s for runs in per_packing]),
            "collapse_s": scatter([runs[step].collapse_s for runs in per_packing]),
        }
        if step != finest:
            entry["paired_difference_to_finest"] = {}
            for name in names:
                diff = np.array([a[name] - b[name] for a, b in zip(values[step], values[finest])])
                spread = float(np.std([v[name] for v in values[finest]], ddof=1))
                entry["paired_difference_to_finest"][name] = {
                    "mean": round(float(diff.mean()), 4),
                    "standard_error": round(float(diff.std(ddof=1) / np.sqrt(len(diff))), 4),
                    "mean_over_packing_scatter": round(float(diff.mean()) / spread, 3) if spread > 0 else None,
                }
            entry["speedup_over_finest"] = round(
                np.mean([runs[finest].settle_s + runs[finest].collapse_s for runs in per_packing])
                / np.mean([runs[step].settle_s + runs[step].collapse_s for runs in per_packing]),
                2,
            )
        out[f"{step:g}"] = entry
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size-scales", default="3")
    parser.add_argument("--packings", type=int, default=6)
    parser.add_argument("--steps", default="0.02,0.04", help="dt / contact time, comma-separated")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    steps = [float(s) for s in args.steps.split(",")]
    scales = [float(s) for s in args.size_scales.split(",")]
    jobs = [(s, seed) for s in scales for seed in range(args.packings)]
    started = time.perf_counter()
    result = {
        "benchmark": "time_step",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "load_average_1min_at_start": round(os.getloadavg()[0], 2),
        "column": "quartz, a = 6, L_i = 0.02 m, (mu, e) = (0.39, 0.54), 4 t*",
        "packings": args.packings,
    }
    with ProcessPoolExecutor(args.workers) as pool:
        done = list(pool.map(one_packing, *zip(*jobs), [steps] * len(jobs)))
    for s in scales:
        per_packing = [runs for (scale, _), runs in zip(jobs, done) if scale == s]
        result[f"size_scale_{s:g}"] = {"n_particles": per_packing[0][steps[0]].n_particles} | compare(
            per_packing, steps
        )
    result["seconds"] = round(time.perf_counter() - started, 1)
    result["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
