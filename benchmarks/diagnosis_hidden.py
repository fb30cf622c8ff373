"""Hidden-effect benchmark of the discrepancy diagnosis; prints JSON.

Five synthetic data sets, each made by the builtin DEM with one candidate mechanism switched on
(the five candidates in a seeded random order, each at a random magnitude in its stated hidden
range, random base parameters and a packing seed the diagnosis never uses), plus one null data
set (base model only); measurement noise added (runout std 0.05 L*, deposit height std 0.5 mm).
The diagnosis gets the data and the noise level, never the truth. Target: 5 of 5 named and the
null case "none". Prints the hit rate and, per case, the verdict, the BIC gains (from DEM runs for
the models scored there, from the final emulator fits for every candidate; never mixed), how far the
best candidate's evidence lies from the decision rule's margins, and the error before/after (runout
MSE and chi^2, fit and held out, from DEM runs).

Columns: quartz, L_i = 0.02 m, a = 1 and 2, coarse-grained (size_scale 4: 153 and 307 grains),
runout every 0.5 t* up to 5 t*, and the deposit profile read as another lab or solver would read
it, not as the model would by default (calibration/synthetic.py): 46 points a column (4.6 times the
runout's), in bins of 2 real grain diameters, half a t* after the runout record ends. The model
reads its own profile the same way (dem.runout.profile_at), and the profile counts by its effective
number of points (calibration/residuals.py). About 10-25 minutes on 2 cores (load-dependent).

    python benchmarks/diagnosis_hidden.py [--size-scale 4] [--seed 2024] [--rounds 3] [--quick]
"""

import argparse
import json
import logging
import os
import platform
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from calibration.design_runs import SimulationSettings  # noqa: E402
from calibration.diagnosis import DiagnosisSettings  # noqa: E402
from calibration.synthetic import diagnose_hidden_cases, draw_truth  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-scale", type=float, default=4.0)
    parser.add_argument("--seed", type=int, default=2024, help="draws the order, magnitudes and packings")
    # 3 rounds: with 2, the rolling-resistance extension (its effect on the runout is strongly
    # nonlinear in mu_r and mu together) was DEM-scored at an optimum its emulator had not yet
    # settled on, and tied with side-wall friction or cohesion (seeds 2024 and 7)
    parser.add_argument("--rounds", type=int, default=3, help="DEM scoring rounds (refinement)")
    parser.add_argument(
        "--max-rounds", type=int, default=None, help="most rounds, while the evidence is unsettled (default: --rounds)"
    )
    parser.add_argument("--n-base", type=int, default=10)
    parser.add_argument("--n-per-mechanism", type=int, default=8)
    parser.add_argument(
        "--quick", action="store_true", help="CI-sized: size_scale 5, small design, 1 round (2 where unsettled)"
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    if args.quick:
        args.size_scale, args.n_base, args.n_per_mechanism, args.rounds, args.max_rounds = 5.0, 6, 5, 1, 2
    settings = DiagnosisSettings(
        simulation=SimulationSettings(size_scale=args.size_scale),
        n_base=args.n_base,
        n_per_mechanism=args.n_per_mechanism,
        n_rounds=args.rounds,
        max_rounds=args.max_rounds,
        seed=0,
    )
    mechanisms = [m.mechanism for m in settings.models()[1:]]
    rng = np.random.default_rng(args.seed)
    order = rng.permutation(len(mechanisms))
    truths = [draw_truth(rng, mechanisms[k]) for k in order] + [draw_truth(rng, None)]
    started = time.perf_counter()
    summary = diagnose_hidden_cases(
        truths, settings, seed=args.seed, progress=lambda f: logging.info("hidden cases: %.0f%% done", 100 * f)
    )
    print(
        json.dumps(
            {
                "benchmark": "diagnosis_hidden",
                "date": time.strftime("%Y-%m-%d %H:%M"),
                "machine": platform.processor() or platform.machine(),
                "load_average_1min": os.getloadavg()[0],
                "settings": {
                    "size_scale": args.size_scale,
                    "n_base": args.n_base,
                    "n_per_mechanism": args.n_per_mechanism,
                    "rounds": args.rounds,
                    "max_rounds": args.max_rounds,
                    "seed": args.seed,
                    "runout_noise": 0.05,
                    "profile_noise_m": 5e-4,
                    "decision_rule": settings.rule.to_dict(),
                },
                "hits": summary["hits"],
                "n_hidden": summary["n_hidden"],
                "hit_rate": summary["hit_rate"],
                "null_correct": summary["null_correct"],
                "meets_target": summary["hits"] == summary["n_hidden"] and bool(summary["null_correct"]),
                "cases": [{k: v for k, v in case.items() if k != "result"} for case in summary["cases"]],
                "library_dem_seconds": round(summary["library_seconds"], 1),
                "wall_seconds": round(time.perf_counter() - started, 1),
            },
            indent=1,
            default=float,
        )
    )


if __name__ == "__main__":
    main()
