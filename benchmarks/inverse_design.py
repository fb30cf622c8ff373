"""GNS inverse design on this CPU: online wall time with autograd and with finite differences, the
float32 finite-difference step scan, and parameter recovery on synthetic DEM targets; prints JSON.

Target: online inverse design under 2 minutes with autograd gradients on the default
config (the paper: about 15 minutes on an RTX 3060); recovery of mu within 0.03 with the truth
inside the 95% intervals in at least 4 of 5 targets.

Needs a trained GNS and its dataset from the workflow, e.g. for the default config:
    python -m snakemake --profile workflow/profiles/default results/gns/quartz_multiple/evaluation/summary.json
then
    python benchmarks/inverse_design.py [--dataset quartz_multiple] [--cases 5] [--threads 2]

or with any model and dataset (e.g. a quick one, for timing):
    python benchmarks/inverse_design.py --model M.pt --metadata META.json --cases 0 --skip-multistart --skip-scan

The timed problem is the first recovery target (the mean of 2 DEM packings of the dataset's column
with known (mu, e), noise 0.05 in L*), so the optimiser meets a realistic objective. Each timed run
reports where its online time went: graphs rolled out, rollout steps, forward and backward seconds.
"""

import argparse
import json
import logging
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibration.compare import case_like  # noqa: E402
from calibration.gns_objective import GNSObjective  # noqa: E402
from calibration.inverse import inverse_design  # noqa: E402
from calibration.lbfgsb import FD_STEP, PAPER_START, SCIPY_DEFAULT_STEP  # noqa: E402
from calibration.recovery import (
    PACKINGS_PER_TARGET,
    TRUTH_SEED_OFFSET,
    observation_times,  # noqa: E402
    recovery_study,
    recovery_targets,
    synthetic_measured,
)
from dem.collapse import simulate_collapse  # noqa: E402
from dem.runout import RunoutMethod  # noqa: E402
from gns.dataset import read_metadata, read_training_attrs  # noqa: E402
from gns.simulator import load_simulator  # noqa: E402
from pipeline.inverse_design import model_error_from_evaluation  # noqa: E402

TARGET_ONLINE_S = 120.0


def step_scan(objective: GNSObjective, x) -> dict:
    """Forward-difference gradients of the float32 GNS objective for several steps against autograd."""
    x = np.asarray(x, float)
    _, (exact,) = objective.values_and_gradients(x[None])
    scan = {"autograd": exact.tolist()}
    for h in (SCIPY_DEFAULT_STEP, 1e-6, 1e-4, 1e-3, FD_STEP, 3e-2):
        values = objective.values(np.array([x, x + [h, 0.0], x + [0.0, h]]))
        forward = (values[1:] - values[0]) / h
        scan[f"{h:g}"] = {
            "gradient": forward.tolist(),
            "relative_error": float(np.linalg.norm(forward - exact) / max(np.linalg.norm(exact), 1e-30)),
        }
    return scan


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="quartz_multiple")
    parser.add_argument("--results", default="results")
    parser.add_argument("--cases", type=int, default=5, help="recovery targets (0: skip the recovery)")
    parser.add_argument("--starts", type=int, default=4, help="starts of the multi-start run (also timed: 1 start)")
    parser.add_argument("--recovery-starts", type=int, default=1)
    parser.add_argument("--max-iterations", type=int, default=10, help="per start (evaluations: at most twice that)")
    parser.add_argument("--recovery-gradient", default="autograd", choices=["autograd", "finite-difference"])
    parser.add_argument("--threads", type=int, default=1, help="torch threads (2 on a busy 2-core box is 10x slower)")
    parser.add_argument("--skip-fd", action="store_true", help="do not time the finite-difference arm")
    parser.add_argument("--skip-multistart", action="store_true", help="time 1 start only")
    parser.add_argument("--skip-scan", action="store_true", help="skip the finite-difference step scan")
    parser.add_argument("--packings", type=int, default=PACKINGS_PER_TARGET, help="DEM packings averaged per target")
    parser.add_argument("--model", default=None, help="GNS model (default: RESULTS/gns/DATASET/train/model_best.pt)")
    parser.add_argument(
        "--metadata", default=None, help="dataset metadata (default: RESULTS/datasets/DATASET/metadata.json)"
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    torch.set_num_threads(args.threads)
    results = Path(args.results)
    model_path = Path(args.model or results / "gns" / args.dataset / "train" / "model_best.pt")
    metadata_path = Path(args.metadata or results / "datasets" / args.dataset / "metadata.json")
    if not model_path.exists() or not metadata_path.exists():
        sys.exit(
            f"{model_path} or {metadata_path} missing: train the GNS first, e.g. python -m snakemake --profile "
            f"workflow/profiles/default {results}/gns/{args.dataset}/evaluation/summary.json"
        )
    metadata = read_metadata(metadata_path)
    simulator = load_simulator(model_path, metadata)
    runout = RunoutMethod()  # the project's default (config key runout); the evaluation must match it
    evaluation = results / "gns" / args.dataset / "evaluation" / "summary.json"
    evaluation = evaluation if evaluation.exists() else None
    trained = read_training_attrs(metadata)
    reference = trained[0]
    t_points = observation_times(float(reference.get("duration_over_tstar", 4.0)))
    model_error = model_error_from_evaluation(evaluation, runout, t_points)

    t0 = time.perf_counter()
    start = simulate_collapse(case_like(reference, *PAPER_START, seed=TRUTH_SEED_OFFSET - 1))
    truth_params = recovery_targets(trained, 1)[0]
    truths = [
        simulate_collapse(case_like(reference, *map(float, truth_params), seed=TRUTH_SEED_OFFSET + j)) for j in range(2)
    ]
    dem_s = (time.perf_counter() - t0) / 3
    measured = synthetic_measured(truths, t_points, 0.05, seed=0, name="timed_target", runout=runout)  # 2 packings
    objective = GNSObjective(simulator, start, measured, runout=runout)
    out = {
        "device": platform.processor() or platform.machine(),
        "torch_threads": args.threads,
        "cpu_count": os.cpu_count(),
        "load_average": os.getloadavg(),
        "dataset": args.dataset,
        "n_particles": start.n_particles,
        "rollout_steps": objective.n_steps,
        "t_over_tstar": t_points.tolist(),
        "dem_run_s": dem_s,
        "model_error_std": None if model_error is None else model_error.tolist(),
        "timed_target": [float(v) for v in truth_params],
        "target_online_s": TARGET_ONLINE_S,
    }
    runs = (
        [("autograd", 1)]
        + ([] if args.skip_multistart else [("autograd", args.starts)])
        + ([] if args.skip_fd else [("finite-difference", 1)])
    )
    for gradient, starts in runs:
        result = inverse_design(
            simulator,
            start,
            measured,
            metadata,
            trained,
            gradient=gradient,
            n_starts=starts,
            max_iterations=args.max_iterations,
            model_error_std=model_error,
            runout=runout,
        )
        seconds = result.seconds
        rollouts = sum(len(s.evaluations.values) for s in result.starts)
        key = f"{gradient}_{starts}_start{'s' if starts > 1 else ''}"
        out[key] = {
            "online_s": result.seconds["online"],
            "optimisation_s": result.seconds["optimisation"],
            "posterior_s": result.seconds["posterior"],
            "batches": result.n_batches,
            "evaluations": rollouts,
            "rollouts": seconds["online_rollouts"],
            "rollout_steps": seconds["rollout_steps"],
            "forward_s": seconds["online_forward"],
            "backward_s": seconds["online_backward"],
            "other_s": seconds["online"] - seconds["online_forward"] - seconds["online_backward"],
            "iterations": [s.n_iterations for s in result.starts],
            "optimum": result.best_params,
            "gns_objective": result.best_value,
            "seconds_per_batch": result.seconds["optimisation"] / max(result.n_batches, 1),
            "posterior": [
                {k: p[k] for k in ("name", "value", "low", "high", "identifiable")}
                for p in result.posterior["parameters"]
            ],
        }
        print(json.dumps({key: out[key]}), file=sys.stderr)
    out["meets_target"] = {k: v["online_s"] < TARGET_ONLINE_S for k, v in out.items() if k.startswith("autograd")}
    if not args.skip_scan:
        out["fd_step_scan_at_start"] = step_scan(objective, PAPER_START)
    if args.cases:
        summary = recovery_study(
            simulator,
            metadata,
            n_cases=args.cases,
            model_error=(lambda t: model_error_from_evaluation(evaluation, runout, t)) if evaluation else None,
            n_starts=args.recovery_starts,
            max_iterations=args.max_iterations,
            gradient=args.recovery_gradient,
            packings=args.packings,
        )
        out["recovery"] = {k: v for k, v in summary.items() if k != "cases"}
        out["recovery"]["cases"] = [
            {
                k: r[k]
                for k in (
                    "truth",
                    "estimate",
                    "interval",
                    "identifiable",
                    "inside",
                    "mu_error",
                    "objective",
                    "online_s",
                )
            }
            for r in summary["cases"]
        ]
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
