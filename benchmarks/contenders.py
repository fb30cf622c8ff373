"""The contenders check (calibration/contenders.py) rerun on a finished DAG's diagnoses with other
pairs of mechanisms; prints JSON.

    python benchmarks/contenders.py DAG [--column quartz] [--pairs auto | a+b,c+d | none]
        [--config config/config.yaml] [--out FOLDER]

DAG: the folder of a finished `bash run.sh main` (its results/diagnosis/<column>/diagnosis.json).
For each column, the stage's own function (pipeline.calibrated_contenders.run_contenders) with the
config's calibration section, its contender_pairs replaced by --pairs: every DEM-scored model of the
diagnosis and each pair at its fit, predicted across a, moved to the target grain size, and the
choice. The JSON gives, per column and contender: parameters, DEM BIC, law chi^2, the move's MSE and
chi^2, the combined score, plausibility, the fraction of the law per a, the pair's fit (start, MSE
before and after, DEM runs, seconds), and the choice. contenders.json and its figure go to --out
(default DAG.contenders/<column>_<pairs>.{json,png}); the DAG itself is not touched.
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import asdict
from pathlib import Path

import yaml

from pipeline.calibrated_contenders import run_contenders
from pipeline.config_schema import validate_config

ROOT = Path(__file__).resolve().parent.parent


def pairs_argument(text: str) -> str | list[list[str]]:
    """auto, none (no pair) or a+b,c+d as calibration.contender_pairs reads them."""
    if text in ("auto", "none"):
        return "auto" if text == "auto" else []
    return [pair.split("+") for pair in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dag", type=Path)
    parser.add_argument("--column", action="append", help="measured column(s); default: every one")
    parser.add_argument("--pairs", default="auto")
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    config = validate_config(yaml.safe_load(args.config.read_text()), ROOT / "workflow/schemas/config.schema.yaml")
    section = dict(config["calibration"], contender_pairs=pairs_argument(args.pairs))
    out = args.out or Path(f"{args.dag}.contenders")
    out.mkdir(parents=True, exist_ok=True)
    report = {"dag": str(args.dag), "pairs": args.pairs, "columns": {}}
    for name in args.column or sorted(config["measured"]):
        stem = out / f"{name}_{args.pairs.replace(',', '_')}"
        choice = run_contenders(
            ROOT / config["measured"][name],
            args.dag / "results" / "diagnosis" / name / "diagnosis.json",
            stem.with_suffix(".json"),
            stem.with_suffix(".png"),
            section,
            config["diagnosis"],
            config.get("runout"),
            config["dem"],
            name=name,
        )
        report["columns"][name] = {
            "chosen": choice.chosen,
            "by_fit": choice.by_fit,
            "seconds": choice.seconds,
            "contenders": [
                {
                    "model": c.model,
                    "parameters": c.parameters,
                    "bic": c.bic,
                    "law_chi2": c.law_chi2,
                    "move_mse": None if c.grain_shift is None else c.grain_shift.shift_mse,
                    "move_chi2": c.transfer_chi2,
                    "combined": c.combined,
                    "physical": c.physical,
                    "switched_off": c.switched_off,
                    "law_fraction": c.scaling.runout_fraction(),
                    "pair_fit": None if c.pair_fit is None else asdict(c.pair_fit),
                }
                for c in choice.contenders
            ],
        }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
