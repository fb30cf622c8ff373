"""How close any surrogate can come to one DEM runout curve: the chaos floor of the test split; prints JSON.

  python benchmarks/gns_floor.py [--dataset results/datasets/quartz_multiple/metadata.json]
                                 [--model results/gns/quartz_multiple/train/model_best.pt]
                                 [--reruns 6] [--perturbation 1e-3] [--figure PATH]
                                 [--runout dense_front_reached]

A GNS rollout starts from the first C frames of a DEM run and is scored against the rest of that
one run (gns.evaluate.rollout_runout_mse). A granular collapse is chaotic: the builtin DEM rerun from the
same settled packing with every grain moved by `perturbation` mean diameters (normal, seeded),
far below any overlap that matters, ends on a different runout curve. For every test case this
reruns the DEM `reruns` times (dem.runout_study.perturbed_reruns) and reports, with L* read by
the runout method `--runout` (dem.runout; every method side by side: benchmarks/runout_methods.py):

  rerun_mse         mean over reruns of the runout MSE of a rerun against the original: what a
                    surrogate that is exactly a DEM (one more realisation) would score
  ideal_mse         mean over frames of the variance of L* across the original and its reruns:
                    what the best deterministic surrogate (the conditional mean curve) would
                    score on average; it is half of rerun_mse when the runs are independent
  gns_mse           the model's runout MSE against the original (as in the evaluation)
  gns_mse_to_mean   the model's runout MSE against the mean of all runs
Each also split by the paper's phases (free fall t/t* <= 1, spreading <= 2.5, stopping). The
target set for the GNS is a test runout MSE of 0.05; `target_below_floor` says whether ideal_mse exceeds it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dem.runout import METHODS, RunoutMethod  # noqa: E402


def rounded(value, digits: int = 4):
    """A JSON-ready copy with every float rounded to `digits` (the benchmark prints its figures)."""
    if isinstance(value, dict):
        return {k: rounded(v, digits) for k, v in value.items()}
    if isinstance(value, list):
        return [rounded(v, digits) for v in value]
    return round(value, digits) if isinstance(value, float) else value


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="results/datasets/quartz_multiple/metadata.json")
    parser.add_argument(
        "--model", default=None, help="default results/gns/<dataset name>/train/model_best.pt; skipped when absent"
    )
    parser.add_argument("--reruns", type=int, default=6)
    parser.add_argument("--perturbation", type=float, default=1e-3, help="mean grain diameters")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--figure", default=None, help="runout curves of every run and the GNS (PNG)")
    parser.add_argument("--runout", choices=METHODS, default=RunoutMethod().method, help="runout method (dem.runout)")
    args = parser.parse_args()
    os.environ["NUMBA_NUM_THREADS"] = str(args.threads)
    import torch

    from dem.runout_study import chaos_floor, perturbed_reruns
    from dem.trajectory import read_trajectory
    from gns.dataset import read_metadata, split_paths
    from gns.rollout import rollout_trajectory
    from gns.simulator import load_simulator

    torch.set_num_threads(args.threads)
    metadata = read_metadata(args.dataset)
    model_path = Path(args.model or f"results/gns/{metadata['name']}/train/model_best.pt")
    simulator = load_simulator(model_path, metadata) if model_path.exists() else None
    method = RunoutMethod(args.runout)
    cases, plotted = [], []
    for k, path in enumerate(split_paths(metadata, "test")):
        dem = read_trajectory(path)
        t, original = method.curve(dem)
        reruns = np.array(
            [method.curve(r)[1] for r in perturbed_reruns(dem, args.reruns, args.perturbation, args.seed + k)]
        )
        gns_curve, problem = None, None
        if simulator is not None:
            gns = rollout_trajectory(simulator, dem, on_invalid="flag")
            if gns.attrs["rollout_valid"]:
                gns_curve = method.curve(gns)[1]
            else:
                problem = gns.attrs["rollout_problem"]
        row = {
            "case": Path(path).stem,
            "friction": float(dem.attrs["friction"]),
            "restitution": float(dem.attrs["restitution"]),
            **rounded(chaos_floor(t, original, reruns, gns_curve)),
        }
        if problem:
            row["gns_problem"] = problem
        cases.append(row)
        plotted.append((row["case"], t, np.vstack([original, reruns]), gns_curve))
        print(json.dumps({k: row[k] for k in ("case", "rerun_mse", "ideal_mse")}), file=sys.stderr, flush=True)

    mean = lambda key: round(float(np.mean([c[key] for c in cases])), 4) if all(key in c for c in cases) else None  # noqa: E731
    summary = {
        "dataset": metadata["name"],
        "model": str(model_path) if simulator is not None else None,
        "reruns": args.reruns,
        "perturbation_diameters": args.perturbation,
        "seed": args.seed,
        "runout": method.to_config(),
        "rerun_mse": mean("rerun_mse"),
        "ideal_mse": mean("ideal_mse"),
        "gns_mse": mean("gns_mse"),
        "gns_mse_to_mean": mean("gns_mse_to_mean"),
        "target_mse": 0.05,
        "target_below_floor": mean("ideal_mse") > 0.05,
        "cases": cases,
    }
    if args.figure:
        plot(plotted, args.figure)
    print(json.dumps(summary, indent=1))


def plot(plotted, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.plots import save_figure

    fig, axes = plt.subplots(1, len(plotted), figsize=(4.2 * len(plotted), 3.6), squeeze=False)
    for ax, (name, t, runs, gns_curve) in zip(axes[0], plotted):
        ax.plot(t, runs[1:].T, color="0.7", lw=0.8)
        ax.plot(t, runs[0], color="tab:orange", lw=1.5, label="DEM (scored against)")
        ax.plot(t, runs.mean(axis=0), color="k", ls=":", label="mean of runs")
        if gns_curve is not None:
            ax.plot(t, gns_curve, color="tab:blue", ls="--", label="GNS")
        ax.set(title=f"{name}: DEM reruns (grey)", xlabel="t / t*", ylabel="L*")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    main()
