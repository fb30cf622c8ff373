"""The answer one scale finer, predicted against kept: on a finished DAG, the target's own parameters
run at the finer scale beside the parameters the DAG predicted for it; prints JSON.

    python benchmarks/finer_scale.py DAG [--column quartz] [--packings 4]

DAG: the folder of a finished `bash run.sh main` whose calibration carried the answer to a target
(results/calibrated/<column>/calibrated.json with `target` and `transfer`). The DAG's held-out
transfer runs the parameters calibration.target_scale.predict_finer gave for the finer scale; this
runs the target's answer itself there, on the same validation packings (seeds 5001, ...), with the
calibrated stage's own validate. Per column: the target's validated MSE, the finer scale's MSE with
the target's parameters and with the predicted ones, each as a ratio to the target's (the transfer
issue's bound is 3), the predicted MSE, the measured coarse-to-target move of the curve, the runs'
seconds, and the move of the model's own curve from the target to the finer scale at the target's
parameters (resolution_shift). The DAG is not touched.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import yaml  # noqa: E402
from gns_speed import machine  # noqa: E402 - the date, machine and load every benchmark prints

from calibration.calibrated import read_model, validate  # noqa: E402
from calibration.calibrated_result import CalibratedResult  # noqa: E402
from calibration.design_runs import SimulationSettings  # noqa: E402
from calibration.measured import load_column  # noqa: E402
from calibration.target_scale import resolution_shift  # noqa: E402
from dem.runout import RunoutMethod  # noqa: E402
from pipeline.config_schema import validate_config  # noqa: E402

SCHEMA = Path(__file__).resolve().parents[1] / "workflow/schemas/config.schema.yaml"


def column_record(dag: Path, name: str, packings: int) -> dict:
    result = CalibratedResult.from_json(dag / "results" / "calibrated" / name / "calibrated.json")
    target, transfer = result.target, result.transfer
    if not target or not transfer:
        raise SystemExit(f"{name}: calibrated.json has no target or no transfer (calibration.target_size_scale)")
    measured = Path(result.measured)
    column = load_column(measured if measured.is_absolute() else dag / measured)
    runout = column.runout_reading(RunoutMethod.from_config(result.runout))
    validation = target["validation"]
    config = validate_config(yaml.safe_load((dag / "config/config.yaml").read_text()), SCHEMA)
    model, _ = read_model(dag / "results" / "calibrated" / name / "model.json", config["diagnosis"]["channel_width"])
    finer = SimulationSettings(size_scale=float(transfer["size_scale"]))
    kept = validate(
        "the target's parameters", model, column, list(validation["parameters"].values()), finer, runout,
        {"engine": result.engine}, packings,
    )  # fmt: skip
    reference = validation["mse"]
    shift, least = resolution_shift(validation["mean"], kept.mean, reference)
    predicted = target.get("finer") or {}
    return {
        "target_size_scale": target["size_scale"],
        "finer_size_scale": finer.size_scale,
        "target": {"parameters": validation["parameters"], "mse": reference, "mse_se": validation["mse_se"]},
        "kept_at_finer": {
            "mse": kept.mse,
            "mse_se": kept.mse_se,
            "ratio": kept.mse / reference,
            "seconds": kept.seconds,
        },
        "predicted_at_finer": {
            "parameters": transfer["parameters"],
            "mse": transfer["mse"],
            "mse_se": transfer["mse_se"],
            "ratio": transfer["mse"] / reference,
            "predicted_mse": predicted.get("predicted_mse"),
            "coarse_to_target_shift_mse": predicted.get("shift_mse"),
            "factor": predicted.get("factor"),
        },
        "own_curve_target_to_finer": {"shift_mse": shift, "least_mse_kept_parameters": least},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dag", type=Path)
    parser.add_argument("--column", action="append", help="default: quartz and copper")
    parser.add_argument("--packings", type=int, default=4, help="as the DAG's validation_packings (4)")
    args = parser.parse_args()
    started = time.perf_counter()
    out = {"run": machine()}
    for name in args.column or ["quartz", "copper"]:
        out[name] = column_record(args.dag.resolve(), name, args.packings)
    out["seconds"] = time.perf_counter() - started
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
