"""How the runout changes with grain size: one parameter set from coarse grains to real ones; prints JSON.

The measured quartz column (a = 6, L_i = 0.02 m) at (mu, e) = (0.39, 0.54) is settled and
collapsed over 4 t* at size_scale 5, 4, 3, 2, 1.5 and 1 (real grains), on --packings packings
each (seeds 0, 1, ...), two runs at a time (one per core). Reported per scale: grains, grains
across, L* at t/t* = 1, 2, 3.5 and 4 (mean and packing scatter), the final deposit height over
H_i, and the cost per run (settle and collapse seconds, particle-steps/s). Runout read by the
project's default method (config key runout). --figure writes L*(t/t*) per scale and the final
L* and height against scale.

    python benchmarks/scale_ladder.py [--scales 5,4,3,2,1.5,1] [--packings 2] [--figure PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dem.case import CollapseCase  # noqa: E402
from dem.runout import RunoutMethod, final_height  # noqa: E402

READ_AT = (1.0, 2.0, 3.5, 4.0)  # t/t* at which L* is reported


def column(size_scale: float, seed: int) -> CollapseCase:
    return CollapseCase(
        "quartz", 0.02, 6.0, 0.39, 0.54, seed=seed, size_scale=size_scale, name=f"s{size_scale:g}_seed{seed}"
    )


def one_run(size_scale: float, seed: int) -> dict:
    """Settle and collapse one packing (one thread); L*(t/t*), final height and cost."""
    from dem.collapse import simulate_collapse
    from dem.packing import settle_column

    case = column(size_scale, seed)
    start = time.perf_counter()
    packing = settle_column(case)
    settle_s = time.perf_counter() - start
    trajectory = simulate_collapse(case, packing)
    t, runout = RunoutMethod().curve(trajectory)
    height = final_height(np.asarray(trajectory.positions[-1], float), trajectory.radius)
    print(f"size_scale {size_scale:g} seed {seed}: done", file=sys.stderr, flush=True)
    return {
        "size_scale": size_scale,
        "seed": seed,
        "t_over_tstar": t.tolist(),
        "runout": runout.tolist(),
        "final_height_over_H_i": height / case.H_i,
        "settle_s": settle_s,
        "collapse_s": float(trajectory.attrs["wall_time_s"]),
        "particle_steps_per_second": float(trajectory.attrs["particle_steps_per_second"]),
    }


def summarise(runs: list[dict]) -> dict:
    case = column(runs[0]["size_scale"], 0)
    t = np.array(runs[0]["t_over_tstar"])
    curves = np.array([r["runout"] for r in runs])
    at = {f"{x:g}": [round(float(np.interp(x, t, c)), 3) for c in curves] for x in READ_AT}
    return {
        "n_particles": case.n_particles,
        "grains_across": round(case.grains_across, 1),
        "runout_at": {k: {"mean": round(float(np.mean(v)), 3), "per_packing": v} for k, v in at.items()},
        "final_height_over_H_i": [round(r["final_height_over_H_i"], 4) for r in runs],
        "settle_s": [round(r["settle_s"], 1) for r in runs],
        "collapse_s": [round(r["collapse_s"], 1) for r in runs],
        "particle_steps_per_second": [round(r["particle_steps_per_second"]) for r in runs],
    }


def draw(summary: dict, runs: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_curve, ax_scale) = plt.subplots(1, 2, figsize=(10, 4))
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(summary)))
    for colour, (scale, entry) in zip(colours, summary.items()):
        curves = [r for r in runs if f"{r['size_scale']:g}" == scale]
        t = np.array(curves[0]["t_over_tstar"])
        mean = np.mean([r["runout"] for r in curves], axis=0)
        for r in curves:
            ax_curve.plot(t, r["runout"], color=colour, alpha=0.3, lw=0.8)
        ax_curve.plot(t, mean, color=colour, label=f"size_scale {scale} ({entry['n_particles']} grains)")
    ax_curve.set(xlabel="t/t*", ylabel="L* = (L - L_i)/L_i", title="quartz a = 6, (mu, e) = (0.39, 0.54)")
    ax_curve.legend(fontsize=7)
    scales = [float(s) for s in summary]
    final = [summary[s]["runout_at"]["4"]["per_packing"] for s in summary]
    ax_scale.plot(
        np.repeat(scales, [len(f) for f in final]), np.concatenate(final), "o", color="C0", alpha=0.5, label="L*(4 t*)"
    )
    ax_scale.plot(scales, [np.mean(f) for f in final], "-", color="C0")
    ax_scale.set(xlabel="size_scale (grain diameter / real)", ylabel="L* at t/t* = 4", xscale="log")
    twin = ax_scale.twinx()
    heights = [np.mean(summary[s]["final_height_over_H_i"]) for s in summary]
    twin.plot(scales, heights, "s--", color="C3", label="final height / H_i")
    twin.set_ylabel("final deposit height / H_i", color="C3")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scales", default="5,4,3,2,1.5,1")
    parser.add_argument("--packings", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--figure", default=None)
    args = parser.parse_args()
    scales = [float(s) for s in args.scales.split(",")]
    jobs = [(s, seed) for s in sorted(scales) for seed in range(args.packings)]  # finest (longest) first
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        runs = list(pool.map(one_run, *zip(*jobs)))
    summary = {f"{s:g}": summarise([r for r in runs if r["size_scale"] == s]) for s in scales}
    if args.figure:
        draw(summary, runs, args.figure)
    print(
        json.dumps(
            {
                "benchmark": "scale_ladder",
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "machine": f"{os.cpu_count()} cores, {args.workers} runs at a time",
                "load_average_1min_at_end": round(os.getloadavg()[0], 2),
                "wall_s": round(time.perf_counter() - start, 1),
                "case": {"material": "quartz", "L_i": 0.02, "aspect_ratio": 6.0, "friction": 0.39, "restitution": 0.54},
                "runout_method": RunoutMethod().label,
                "by_size_scale": summary,
                "figure": args.figure,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
