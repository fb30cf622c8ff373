"""Synthetic campaigns calibrated by every campaign route, each column predicted from the others;
prints JSON.

    python benchmarks/campaigns.py [--solver builtin|liggghts|both] [--campaigns 2] [--size-scale 4]
        [--aspect-ratios 1,2,4] [--L-i 0.01] [--noise 0.05] [--budget 12] [--out FOLDER]

Each campaign is a hidden truth (calibration.synthetic.draw_truth: mu, e in [0.4, 0.8] and a hidden
mechanism, in turn rolling resistance then side-wall friction (LIGGGHTS: cohesion), on a packing of
its own) "measured" on columns of quartz of the given a and L_i, by the builtin DEM (the model that
fits it) or by LIGGGHTS (another contact law, its own packing and runout reading; skipped where
LIGGGHTS is absent), with Gaussian noise of the given std in L*. The campaign is then calibrated by
the stage's own route functions (pipeline.campaign.run_campaign_route) as the hidden mechanism's
model over its whole box, at the same size_scale: the DoE (face-centred CCD, 1 centre replicate) and
the BO on DEM (--budget points); the GNS route needs a trained GNS and runs in the DAG only. Per
campaign and route: the optimum and the truth, the validated MSE per column, each held-out column's
MSE against its scatter bound, and the DEM runs and seconds an added column costs.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np

from calibration.campaign import Campaign, CampaignRunner
from calibration.design_runs import SimulationSettings
from calibration.mechanisms import get_mechanisms
from calibration.model import Model
from calibration.synthetic import draw_truth, liggghts_measurement, synthetic_columns, synthetic_measurement
from dem.runout import RunoutMethod
from pipeline.campaign import run_campaign_route

# hidden mechanisms, in turn, of each solver's campaigns (LIGGGHTS models no side-wall friction)
MECHANISMS = {"builtin": ("rolling_resistance", "sidewall_friction"), "liggghts": ("rolling_resistance", "cohesion")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--solver", choices=["builtin", "liggghts", "both"], default="both")
    parser.add_argument("--campaigns", type=int, default=2, help="hidden truths per solver")
    parser.add_argument("--size-scale", type=float, default=4.0)
    parser.add_argument("--aspect-ratios", default="1,2,4")
    parser.add_argument("--L-i", type=float, default=0.01)
    parser.add_argument("--noise", type=float, default=0.05, help="std of L* added to the truth")
    parser.add_argument("--budget", type=int, default=12, help="BO points (each one run per column)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("/tmp/campaigns_benchmark"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    solvers = ["builtin", "liggghts"] if args.solver == "both" else [args.solver]
    if "liggghts" in solvers and shutil.which("liggghts") is None:
        solvers.remove("liggghts")
    settings = SimulationSettings(size_scale=args.size_scale)
    ratios = [float(a) for a in args.aspect_ratios.split(",")]
    rng = np.random.default_rng(args.seed)
    section = {"doe_centre_replicates": 1, "budget": args.budget, "n_initial": max(4, args.budget // 3), "seed": 0}
    section["validation_packings"] = 4
    out = {"settings": vars(args) | {"out": str(args.out)}, "solvers": solvers, "campaigns": []}
    for solver in solvers:
        for k in range(args.campaigns):
            mechanism = get_mechanisms([MECHANISMS[solver][k % len(MECHANISMS[solver])]])[0]
            truth = draw_truth(rng, mechanism)
            columns = synthetic_columns("quartz", args.L_i, ratios, profile_step_diameters=None)
            measure = synthetic_measurement if solver == "builtin" else liggghts_measurement
            started = time.perf_counter()
            measured, _ = measure(truth, columns, [mechanism], settings, args.noise, 0.001, rng)
            campaign = Campaign(f"{solver}_{k}", tuple(measured))
            runner = CampaignRunner(campaign, Model(mechanism), settings, RunoutMethod(), {"engine": "builtin"})
            entry = {"solver": solver, "truth": truth.to_dict(), "truth_seconds": time.perf_counter() - started}
            entry["routes"] = []
            for route in ("doe", "bayesopt"):
                folder = args.out / campaign.name
                result = run_campaign_route(runner, route, folder / f"{route}.json", folder / f"{route}.png", section)
                entry["routes"].append(result.summary())
                print(json.dumps({"campaign": campaign.name, **entry["routes"][-1]}), flush=True)
            out["campaigns"].append(entry)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
