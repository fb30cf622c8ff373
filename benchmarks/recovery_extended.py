"""Parameter recovery through the calibrated model's GNS: synthetic DEM targets of the
extended model, recovered by the GNS inverse design over all its parameters; prints JSON.

    python benchmarks/recovery_extended.py [--name quartz] [--targets 5] [--packings 4] [--noise 0.05]

Reads the DAG's outputs of measured column `name` (run the default DAG first): model.json, the
model's GNS (results/gns/calibrated_<name>/), its dataset and test-split evaluation, the start run
(results/inverse/<name>/start.h5) and the measured CSV (its t/t* points and geometry).

Targets: a seeded Latin hypercube over the inner 80% of the range the GNS is trained on; each
target is the mean of `packings` builtin-DEM runs of the model at its truth (packings no dataset or
validation uses) plus measurement noise `noise` (L*, per point), stated with the std of such a mean
(calibration.recovery.synthetic_measured). Each is recovered by calibration.inverse.inverse_design
over every parameter of the model as the DAG's rule calibrated_inverse runs it (the config's
calibration.gns_optimiser, gns_budget and start_packings), with the GNS's test-split runout error
(per t/t* point) in the noise model. Per target and parameter it reports the estimate, the 95%
interval, whether the truth lies inside, and the interval's half-width beside the half-width a
perfect model of the mean response would give: the Cramer-Rao bound 1.96 sqrt(diag((J^T C^-1 J)^-1))
with C the target's own noise (no model error) and J the Jacobian of L* at the optimum (the GNS's:
the best estimate of the mean response's slopes at hand). As in the DAG, the GNS's response to each
parameter is checked against its dataset's DEM runs (calibration.sensitivity): a parameter it does
not resolve, or resolves where the DEM is flat, has its bounds as interval, and as bound too (the
DEM's flat mean response could not narrow it either); the row lists them (untrusted). Pass targets
(docs/experiments/gns-route.md): the truth inside in at least 4 of 5; half-widths within 2x of the bound.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calibration.calibrated import read_model  # noqa: E402
from calibration.design_runs import SimulationSettings  # noqa: E402
from calibration.emulator import ParameterBox, latin_hypercube  # noqa: E402
from calibration.gns_objective import GNSObjective  # noqa: E402
from calibration.inverse import inverse_design  # noqa: E402
from calibration.measured import load_column  # noqa: E402
from calibration.recovery import packing_scatter, synthetic_measured  # noqa: E402
from calibration.sensitivity import untrusted_slopes  # noqa: E402
from calibration.uncertainty import Z95, finite_difference_jacobian  # noqa: E402
from dem.engines import simulate_case  # noqa: E402
from dem.runout import RunoutMethod, runout_at  # noqa: E402
from dem.trajectory import read_trajectory  # noqa: E402
from gns.dataset import dataset_paths, read_metadata, read_training_attrs  # noqa: E402
from gns.simulator import load_simulator  # noqa: E402
from pipeline.calibrated_gns import start_packing_cases  # noqa: E402
from pipeline.config import validate_config  # noqa: E402
from pipeline.inverse_design import dataset_runs, model_error_from_evaluation  # noqa: E402

TRUTH_SEED0 = 7001  # packings of the targets: no dataset's, calibration's or validation's


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--name", default="quartz", help="the measured column (config key measured)")
    parser.add_argument("--measured", default=None, help="its CSV (default data/measured/<name>_a6.csv)")
    parser.add_argument("--results", default="results")
    parser.add_argument("--targets", type=int, default=5)
    parser.add_argument("--packings", type=int, default=4)
    parser.add_argument("--noise", type=float, default=0.05, help="measurement noise of the targets (L*)")
    parser.add_argument("--size-scale", type=float, default=5.0, help="the model's size_scale (diagnosis.size_scale)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--config", type=Path, default=ROOT / "config/config.yaml", help="the DAG's config")
    args = parser.parse_args()
    section = validate_config(yaml.safe_load(args.config.read_text()), ROOT / "workflow/schemas/config.schema.yaml")[
        "calibration"
    ]

    results = Path(args.results)
    dataset = f"calibrated_{args.name}"
    model, _ = read_model(results / f"calibrated/{args.name}/model.json")
    column = load_column(args.measured or ROOT / f"data/measured/{args.name}_a6.csv")
    metadata = read_metadata(results / f"datasets/{dataset}/metadata.json")
    simulator = load_simulator(results / f"gns/{dataset}/train/model_best.pt", metadata)
    evaluation_path = results / f"gns/{dataset}/evaluation/summary.json"
    evaluation = json.loads(evaluation_path.read_text())
    start = read_trajectory(results / f"inverse/{args.name}/start.h5")
    start.attrs.setdefault(model.mechanism.parameter, model.mechanism.off_value(0.55, 0.73))
    # the rule calibrated_inverse's starts: the start run and packings of the model's dataset
    packings = start_packing_cases(section)
    starts = [start] + [read_trajectory(results / f"dem/{dataset}/trajectories/{c}.h5") for c in packings]
    runout = RunoutMethod.from_config(evaluation["runout"])
    model_error = model_error_from_evaluation(evaluation_path, runout, column.t_over_tstar)  # [K]
    names = list(model.parameter_names)
    trained = np.array([metadata["parameter_ranges"][n] for n in names], float)
    inner = trained.mean(axis=1, keepdims=True) + 0.8 * (trained - trained.mean(axis=1, keepdims=True))
    truths = latin_hypercube(ParameterBox(inner, (False,) * len(names)), args.targets, args.seed)
    settings = SimulationSettings(size_scale=args.size_scale)
    # the GNS's response to each parameter is checked against its dataset's DEM runs, as in the DAG
    reference = dataset_runs([path for _, path in dataset_paths(metadata)], names, column, runout)

    started = time.perf_counter()
    runs = []
    for k, truth in enumerate(truths):
        seeds = [TRUTH_SEED0 + 10 * k + j for j in range(args.packings)]
        runs.append([simulate_case(model.case(column, truth, settings, seed), None) for seed in seeds])
        print(f"target {k}: {np.round(truth, 3).tolist()}, {args.packings} DEM runs", file=sys.stderr, flush=True)
    packing_std, _ = packing_scatter([[runout_at(t, column.t_over_tstar, runout) for t in group] for group in runs])
    dem_seconds = time.perf_counter() - started

    rows = []
    for k, (truth, group) in enumerate(zip(truths, runs)):
        target = synthetic_measured(
            group, column.t_over_tstar, args.noise, args.seed + k, f"target_{k}", packing_std, runout
        )
        result = inverse_design(
            simulator,
            starts,
            target,
            metadata,
            read_training_attrs(metadata),
            design_names=names,
            first_start=[0.55, 0.73, start.attrs[model.mechanism.parameter]],  # the DAG's (inverse.start, off)
            model_error_std=model_error,
            runout=runout,
            seed=args.seed + k,
            optimiser=section["gns_optimiser"],
            budget=section["gns_budget"],
            n_initial=section["gns_n_initial"],
            reference=reference,
        )
        posterior = result.posterior
        # a parameter whose GNS slope the check rejects: its interval is its bounds, and so is the
        # interval a perfect model of the flat mean response could give
        untrusted = untrusted_slopes(result.sensitivity)
        objective = GNSObjective(simulator, starts, target, names, runout=runout)
        steps = result.roughness["jacobian_step"]
        jacobian = finite_difference_jacobian(
            lambda theta, objective=objective: objective.runout_values(np.atleast_2d(theta))[0],
            result.best_params,
            result.bounds,
            steps,
        )
        rows.append(
            {
                "truth": dict(zip(names, map(float, truth))),
                "estimate": dict(zip(names, map(float, result.best_params))),
                "gns_objective": result.best_value,
                "parameters": [
                    {
                        "name": p["name"],
                        "truth": float(truth[j]),
                        "low": p["low"],
                        "high": p["high"],
                        "inside": bool(p["low"] <= truth[j] <= p["high"]),
                        "half_width": 0.5 * (p["high"] - p["low"]),
                        "identifiable": p["identifiable"],
                    }
                    for j, p in enumerate(posterior["parameters"])
                ],
                "bound_half_width": [
                    0.5 * (high - low) if n in untrusted else bound
                    for n, (low, high), bound in zip(names, result.bounds, cramer_rao(jacobian, target.runout_std))
                ],
                "untrusted": sorted(untrusted),
            }
        )
        print(f"target {k}: estimate {np.round(result.best_params, 3).tolist()}", file=sys.stderr, flush=True)
    inside = [all(p["inside"] for p in row["parameters"]) for row in rows]
    ratios = {
        n: [row["parameters"][j]["half_width"] / row["bound_half_width"][j] for row in rows]
        for j, n in enumerate(names)
    }
    summary = {
        "name": args.name,
        "model": model.name,
        "targets": args.targets,
        "packings": args.packings,
        "noise": args.noise,
        "model_error_std": None if model_error is None else model_error.tolist(),
        "optimiser": section["gns_optimiser"],
        "start_packings": len(starts),
        "packing_std": packing_std.tolist(),
        "truth_inside_95_all_parameters": int(sum(inside)),
        "truth_inside_95_by_parameter": {
            n: int(sum(row["parameters"][j]["inside"] for row in rows)) for j, n in enumerate(names)
        },
        "half_width_over_bound_median": {n: float(np.median(r)) for n, r in ratios.items()},
        "dem_seconds": dem_seconds,
        "seconds": time.perf_counter() - started,
        "rows": rows,
    }
    print(json.dumps(summary, indent=1, default=float))


def cramer_rao(jacobian: np.ndarray, target_std: np.ndarray) -> list[float]:
    """95% half-widths [p] a perfect model of the mean response would give: 1.96 sqrt(diag((J^T C^-1
    J)^-1)), J [K, p] the slopes of L* at the optimum, C = diag(target_std^2) the target's own noise."""
    weighted = np.asarray(jacobian, float) / np.asarray(target_std, float)[:, None]
    return (Z95 * np.sqrt(np.diag(np.linalg.pinv(weighted.T @ weighted)))).tolist()


if __name__ == "__main__":
    main()
