"""Does a trained GNS see each of its parameters? Its runout's response against its dataset's DEM runs; prints JSON.

  python benchmarks/gns_sensitivity.py [--dataset results/datasets/calibrated_quartz/metadata.json]
                                       [--model results/gns/<dataset name>/train/model_best.pt]
                                       [--measured data/measured/quartz_a6.csv] [--packings 2]
                                       [--points 16] [--seed 0] [--figure PATH]

The check every GNS inverse design runs (calibration.sensitivity), here on a trained model alone:
the DEM runs of every split of the dataset give the DEM's response of L* at the measured column's
last t/t* to each parameter (a plane fit over the parameters scaled to their trained range); the
GNS rolls out `points` Latin-hypercube points of that range from the first frames of `packings`
of the dataset's runs (their mean L*, as the inverse design scores) and gives its own. Per
parameter: both slopes (L* across the range) with standard errors, and whether the GNS resolves
it. The dataset must be of the measured column (a, L_i, material), as the inverse design's is.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="results/datasets/calibrated_quartz/metadata.json")
    parser.add_argument("--model", default=None, help="default results/gns/<dataset name>/train/model_best.pt")
    parser.add_argument("--measured", default="data/measured/quartz_a6.csv")
    parser.add_argument("--packings", type=int, default=2, help="dataset runs whose first frames start the rollouts")
    parser.add_argument("--points", type=int, default=16, help="GNS points, a Latin hypercube of the trained range")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--runout", default="dense_front_reached", help="runout method (dem.runout)")
    parser.add_argument("--figure", default=None, help="L* against each parameter, DEM and GNS (PNG)")
    args = parser.parse_args()

    import torch
    from scipy.stats import qmc

    from calibration.gns_objective import GNSObjective
    from calibration.inverse_plots import plot_sensitivity
    from calibration.measured import load_column
    from calibration.sensitivity import sensitivity_record
    from dem.runout import RunoutMethod
    from dem.trajectory import read_trajectory
    from gns.dataset import read_metadata
    from gns.simulator import load_simulator
    from pipeline.inverse_design import dataset_runs

    torch.set_num_threads(args.threads)
    metadata = read_metadata(args.dataset)
    model = args.model or f"results/gns/{metadata['name']}/train/model_best.pt"
    simulator = load_simulator(model, metadata)
    names = list(simulator.config.parameter_names)
    column = load_column(args.measured)
    runout = RunoutMethod(args.runout)
    paths = [p for split in ("train", "valid", "test") for p in metadata["splits"].get(split, [])]
    dem = dataset_runs(paths, names, column, runout)
    # the trained range, a hair inside (the model refuses a value outside it)
    bounds = np.array([metadata["parameter_ranges"][n] for n in names], float)
    bounds += np.outer(np.diff(bounds, axis=1)[:, 0] * 1e-6, [1, -1])
    objective = GNSObjective(
        simulator, [read_trajectory(p) for p in paths[: args.packings]], column, names, runout=runout
    )
    unit = qmc.LatinHypercube(d=len(names), seed=args.seed).random(args.points)
    started = time.perf_counter()
    gns_points = bounds[:, 0] + unit * (bounds[:, 1] - bounds[:, 0])
    gns = (gns_points, objective.runout_values(gns_points))
    seconds = time.perf_counter() - started
    record, responses = sensitivity_record(names, bounds, dem, gns)
    summary = {
        "dataset": args.dataset,
        "model": model,
        "dem_runs": len(paths),
        "gns_points": args.points,
        "packings": args.packings,
        "rollout_seconds": round(seconds, 1),
        "why": record["why"],
        "parameters": [
            {k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.to_dict().items()} for r in responses
        ],
    }
    if args.figure:
        result = {"names": names, "bounds": bounds.tolist(), "measured": column.name, "sensitivity": record}
        plot_sensitivity(result, args.figure, title=f"does the GNS of {metadata['name']} see each parameter?")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
