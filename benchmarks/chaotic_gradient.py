"""Does the exact gradient of the GNS objective say which way the objective goes? Prints JSON.

    python benchmarks/chaotic_gradient.py [--name quartz] [--results results] [--points 3]

Reads the DAG's outputs of measured column `name` (run the default DAG first): the calibrated
model's GNS (results/gns/calibrated_<name>/), its dataset, the inverse design's start packings (the
start run and calibration.start_packings - 1 training cases, as rule calibrated_inverse) and
inverse.json (its optimum is the first point; the others are the paper's start and a seeded
Latin-hypercube point).

A granular collapse is chaotic, and so is a GNS rollout of it: the derivative of one rollout with
respect to its parameters grows with the rollout's length, as two nearby rollouts part. The
objective (runout MSE of the mean L* over the start packings) is smooth on average but rough on
small scales. Per point this reports:

  gradient            d objective / d theta by autograd through the rollout (the L-BFGS-B's)
  gradient_by_time    |gradient| (in the units L-BFGS-B steps in) of the objective over the first k
                      measured points, k = 1..K: how it grows with the rollout's length
  along_descent       the objective at steps s (in L-BFGS-B's units) along -gradient and along
                      +gradient, with the change the gradient predicts for each (-|g| s)
  descent_fraction    the share of those steps along -gradient that lower the objective (a
                      gradient that carries the trend: near 1; one that carries only the local
                      roughness: near 0.5)

L-BFGS-B's first step is of length ~1 / |g| in its units: with |g| ~ 1e5 that step is far below the
scale (~0.02 in friction) on which the objective is rough, and the line search can only fail.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calibration.calibrated import read_model  # noqa: E402
from calibration.emulator import ParameterBox, latin_hypercube  # noqa: E402
from calibration.gns_objective import GNSObjective  # noqa: E402
from calibration.inverse import PAPER_WIDTH, design_bounds  # noqa: E402
from calibration.measured import load_column  # noqa: E402
from dem.runout import RunoutMethod  # noqa: E402
from dem.trajectory import read_trajectory  # noqa: E402
from gns.dataset import read_metadata  # noqa: E402
from gns.simulator import load_simulator  # noqa: E402
from pipeline.calibrated_gns import start_packing_cases  # noqa: E402
from pipeline.config import validate_config  # noqa: E402

STEPS = (0.003, 0.01, 0.03, 0.1)  # along the gradient, in L-BFGS-B's units (friction's: 1 = the whole 0.6 range)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--name", default="quartz", help="the measured column (config key measured)")
    parser.add_argument("--config", default=str(ROOT / "config/config.yaml"))
    parser.add_argument("--results", default="results")
    parser.add_argument("--points", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    config = validate_config(
        yaml.safe_load(Path(args.config).read_text()), ROOT / "workflow/schemas/config.schema.yaml"
    )
    results = Path(args.results)
    dataset = f"calibrated_{args.name}"
    model, _ = read_model(results / f"calibrated/{args.name}/model.json")
    column = load_column(config["measured"][args.name])
    metadata = read_metadata(results / f"datasets/{dataset}/metadata.json")
    simulator = load_simulator(results / f"gns/{dataset}/train/model_best.pt", metadata)
    inverse = json.loads((results / f"calibrated/{args.name}/inverse.json").read_text())
    paths = [results / f"inverse/{args.name}/start.h5"] + [
        results / f"dem/{dataset}/trajectories/{case}.h5" for case in start_packing_cases(config["calibration"])
    ]
    starts = [read_trajectory(path) for path in paths]
    off = model.mechanism.off_value(*config["inverse"]["start"]) if model.mechanism else None
    for packing in starts:  # the start run of the base model records no mechanism parameter
        if model.mechanism:
            packing.attrs = {model.mechanism.parameter: off, **packing.attrs}
    names = list(model.parameter_names)
    runout = RunoutMethod.from_config(config.get("runout"))
    bounds = np.array(design_bounds([None] * len(names), names, metadata["parameter_ranges"]))
    scale = np.maximum((bounds[:, 1] - bounds[:, 0]) / PAPER_WIDTH, 1.0)  # as calibration.inverse
    points = [
        np.array(inverse["best_params"]),
        np.clip([0.55, 0.73, off if off is not None else 0][: len(names)], *bounds.T),
    ]
    points += list(latin_hypercube(ParameterBox(bounds, (False,) * len(names)), max(args.points - 2, 0), args.seed))
    objective = GNSObjective(simulator, starts, column, names, runout=runout)

    rows, started = [], time.perf_counter()
    for x in points[: args.points]:
        value, gradient = (a[0] for a in objective.values_and_gradients(x[None]))
        by_time = []
        for k in range(1, len(column.t_over_tstar) + 1):
            first = dataclasses.replace(column, t_over_tstar=column.t_over_tstar[:k], runout=column.runout[:k])
            first = dataclasses.replace(first, runout_std=None if column.runout_std is None else column.runout_std[:k])
            _, g = GNSObjective(simulator, starts, first, names, runout=runout).values_and_gradients(x[None])
            by_time.append(float(np.linalg.norm(g[0] * scale)))
        g_scaled = gradient * scale
        direction = -g_scaled / np.linalg.norm(g_scaled) * scale  # a unit step in L-BFGS-B's units, in parameters
        probes = [np.clip(x + s * direction, *bounds.T) for s in STEPS] + [
            np.clip(x - s * direction, *bounds.T) for s in STEPS
        ]
        values = objective.values(np.array(probes))
        descent, ascent = values[: len(STEPS)], values[len(STEPS) :]
        rows.append(
            {
                "point": dict(zip(names, np.round(x, 4).tolist())),
                "objective": float(value),
                "gradient": dict(zip(names, gradient.tolist())),
                "gradient_norm_scaled": float(np.linalg.norm(g_scaled)),
                "gradient_by_time": {f"{t:g}": n for t, n in zip(column.t_over_tstar, by_time)},
                "along_descent": [
                    {
                        "step": s,
                        "predicted_change": float(-np.linalg.norm(g_scaled) * s),
                        "change_along_minus_gradient": float(d - value),
                        "change_along_plus_gradient": float(a - value),
                    }
                    for s, d, a in zip(STEPS, descent, ascent)
                ],
                "descent_fraction": float(np.mean(descent < value)),
            }
        )
        print(f"point {len(rows)}: |g| {rows[-1]['gradient_norm_scaled']:.3g}", file=sys.stderr, flush=True)
    print(
        json.dumps(
            {
                "benchmark": "chaotic_gradient",
                "name": args.name,
                "model": model.name,
                "start_packings": len(starts),
                "rollout_steps": objective.n_steps,
                "machine": {"cpu": platform.processor() or platform.machine(), "threads": args.threads},
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "seconds": time.perf_counter() - started,
                "points": rows,
                "descent_fraction_overall": float(np.mean([r["descent_fraction"] for r in rows])),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
