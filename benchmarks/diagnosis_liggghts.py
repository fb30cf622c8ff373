"""The discrepancy diagnosis on data from another solver (LIGGGHTS); prints JSON.

benchmarks/diagnosis_hidden.py makes its data with the builtin DEM, the very model the diagnosis
fits. Here the truth is simulated by LIGGGHTS 3.8 (calibration.synthetic.liggghts_measurement,
dem/engines/liggghts_hertz.py): a Hertz contact law (+ SJKR cohesion, + EPSD2 rolling friction,
a floor wall of its own friction), a packing LIGGGHTS settles itself from a lattice, and the runout
read the lab's way (connected front, farthest reached), not the config's (dense front). The data
state that reading (the CSV field `runout_method`), so the diagnosis reads its own runs the same
way (its library is built for columns that state it); otherwise it runs unchanged, with all five
candidates. Cases: rolling resistance, cohesion (its
Bond number turned into SJKR's cohesion energy density by the Hertz + SJKR pull-off force) and
basal friction, each at a random magnitude in its stated hidden range with random (mu, e) and
packing seed, plus a null case; measurement noise as in diagnosis_hidden.py (runout std 0.05 L*,
deposit height std 0.5 mm). Columns: quartz, L_i = 0.02 m, the given aspect ratios, coarse-grained
(size_scale 5 by default: 98, 196 and 392 grains at a = 1, 2 and 4).

Reported: the hit rate and the null case's verdict; per case the verdict, the BIC gains (DEM and
emulator, never mixed) and margins, the held-out gain and the errors before/after
(calibration.synthetic.evidence_margins and the diagnosis' errors). Then a detection threshold per
mechanism: its hidden case's truth rerun at weaker magnitudes (the mechanism's distance from "off"
halved each step; in log(parameter) for basal friction) until the verdict is no longer the
mechanism; the weakest magnitude still named is the threshold. Needs `liggghts` on PATH.

    python benchmarks/diagnosis_liggghts.py [--size-scale 5] [--aspect-ratios 1 2 4] [--seed 16] [--quick]
        [--cases rolling_resistance ...]

--cases diagnoses only the named cases (mechanisms, or `none` for the null case); the truths are
drawn for every case all the same, so a case's truth does not depend on which others run.
"""

import argparse
import json
import logging
import os
import platform
import shutil
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from calibration.design_runs import SimulationSettings  # noqa: E402
from calibration.diagnosis import DiagnosisSettings  # noqa: E402
from calibration.observables import Observables  # noqa: E402
from calibration.synthetic import (  # noqa: E402
    LAB_RUNOUT,
    HiddenTruth,
    diagnose_hidden_cases,
    draw_truth,
    liggghts_measurement,
    synthetic_columns,
)

MECHANISMS = ("rolling_resistance", "cohesion", "basal_friction")  # what the LIGGGHTS deck models
CASES = MECHANISMS + ("none",)  # the hidden cases, in the order their truths are drawn
LADDER = (0.5, 0.25, 0.125)  # fractions of the hidden case's distance from "off"


def weaker(truth: HiddenTruth, mechanism, fraction: float) -> HiddenTruth:
    """`truth` with its mechanism at `fraction` of its distance from the off value (geometric for a
    log-scale parameter)."""
    off = mechanism.off_value(truth.friction, truth.restitution)
    if mechanism.log_scale:
        magnitude = off * (truth.magnitude / off) ** fraction
    else:
        magnitude = off + fraction * (truth.magnitude - off)
    return HiddenTruth(truth.friction, truth.restitution, truth.mechanism, float(magnitude), truth.seed)


def case_record(case: dict) -> dict:
    return {k: v for k, v in case.items() if k != "result"}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-scale", type=float, default=5.0)
    parser.add_argument("--aspect-ratios", type=float, nargs="+", default=[1.0, 2.0, 4.0])
    parser.add_argument("--seed", type=int, default=16, help="draws the truths, the noise and the ladder's noise")
    parser.add_argument("--rounds", type=int, default=2, help="DEM scoring rounds (refinement)")
    parser.add_argument(
        "--max-rounds", type=int, default=None, help="most rounds, while the evidence is unsettled (default: --rounds)"
    )
    parser.add_argument("--n-base", type=int, default=10)
    parser.add_argument("--n-per-mechanism", type=int, default=8)
    parser.add_argument("--ladder", type=int, default=len(LADDER), help="weaker magnitudes tried per mechanism")
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: a = 1 and 2, small design, 1 round (2 where unsettled), 1 rung"
    )
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES), help="the hidden cases to diagnose")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    if shutil.which("liggghts") is None:
        sys.exit("liggghts is not on PATH (Debian: apt-get install liggghts)")
    if args.quick:
        args.aspect_ratios, args.n_base, args.n_per_mechanism, args.rounds, args.ladder = [1.0, 2.0], 6, 5, 1, 1
        args.max_rounds = 2
    settings = DiagnosisSettings(
        simulation=SimulationSettings(size_scale=args.size_scale),
        n_base=args.n_base,
        n_per_mechanism=args.n_per_mechanism,
        n_rounds=args.rounds,
        max_rounds=args.max_rounds,
        seed=0,
    )
    started = time.perf_counter()
    # the columns state the lab's reading, so the library reads its runs as the data will be read
    columns = synthetic_columns(aspect_ratios=args.aspect_ratios, runout_method=LAB_RUNOUT.method)
    observables = Observables(columns, settings.runout)
    library = settings.library(observables)
    known = {m.mechanism.name: m.mechanism for m in settings.models()[1:]}
    rng = np.random.default_rng(args.seed)
    drawn = [draw_truth(rng, known[name]) for name in MECHANISMS] + [draw_truth(rng, None)]
    truths = [truth for name, truth in zip(CASES, drawn) if name in args.cases]

    def diagnosed(truths, seed):
        return diagnose_hidden_cases(
            truths,
            settings,
            columns,
            seed=seed,
            library=library,
            measurement=liggghts_measurement,
            progress=lambda f: logging.info("LIGGGHTS cases: %.0f%% done", 100 * f),
        )

    summary = diagnosed(truths, args.seed)
    thresholds = {}
    for k, name in enumerate(name for name in CASES if name in args.cases and name != "none"):
        hidden = summary["cases"][k]
        ladder = [{"magnitude": hidden["truth"]["magnitude"], "cause": hidden["cause"]}]
        for step, fraction in enumerate(LADDER[: args.ladder]):
            if ladder[-1]["cause"] != name:
                break
            truth = weaker(truths[k], known[name], fraction)
            (case,) = diagnosed([truth], args.seed + 100 * (CASES.index(name) + 1) + step)["cases"]
            ladder.append({"magnitude": truth.magnitude, "cause": case["cause"], **case["margins"]})
        named = [rung["magnitude"] for rung in ladder if rung["cause"] == name]
        missed = [rung["magnitude"] for rung in ladder if rung["cause"] != name]
        thresholds[name] = {
            "parameter": known[name].parameter,
            "off_value_at_truth": known[name].off_value(truths[k].friction, truths[k].restitution),
            "hidden_range": list(known[name].hidden_range),
            "weakest_named": named[-1] if named else None,  # the threshold: rungs grow weaker
            "strongest_missed": missed[0] if missed else None,
            "ladder": ladder,
        }
    print(
        json.dumps(
            {
                "benchmark": "diagnosis_liggghts",
                "date": time.strftime("%Y-%m-%d %H:%M"),
                "machine": platform.processor() or platform.machine(),
                "load_average_1min": os.getloadavg()[0],
                "settings": {
                    "size_scale": args.size_scale,
                    "aspect_ratios": args.aspect_ratios,
                    "n_base": args.n_base,
                    "n_per_mechanism": args.n_per_mechanism,
                    "rounds": args.rounds,
                    "max_rounds": args.max_rounds,
                    "seed": args.seed,
                    "cases": args.cases,
                    "runout_noise": 0.05,
                    "profile_noise_m": 5e-4,
                    "data_runout": LAB_RUNOUT.to_config(),
                    "model_runout": observables.reading(columns[0]).to_config(),  # as the data state
                    "decision_rule": settings.rule.to_dict(),
                },
                "hits": summary["hits"],
                "n_hidden": summary["n_hidden"],
                "hit_rate": summary["hit_rate"],
                "null_correct": summary["null_correct"],
                "cases": [case_record(case) for case in summary["cases"]],
                "detection_thresholds": thresholds,
                "library_dem_seconds": round(summary["library_seconds"], 1),
                "wall_seconds": round(time.perf_counter() - started, 1),
            },
            indent=1,
            default=float,
        )
    )


if __name__ == "__main__":
    main()
