"""Every runout method on the same DEM runs: packing scatter per phase, flicker, chaos floor; prints JSON.

  python benchmarks/runout_methods.py [--config config/config.yaml] [--packings 8] [--reruns 8]
                                      [--results results] [--figure PATH] [--threads 1]

The cases are the default config's GNS test cases (the test split of every dataset in
gns.datasets) and the DoE design centre of every column in doe.measured (the measured quartz
column at mu = e = 0.6, coarse-grained as the DoE runs it). Each case is run once in the builtin
DEM from its own seed (exactly the DAG's run), then `--packings` more times from new packings (the
scatter) and `--reruns` times from its own packing with every grain moved by 0.001 diameters (the
chaos floor of benchmarks/gns_floor.py). Where the DAG has trained the GNS
(`<results>/gns/<dataset>/train/model_best.pt`), the test cases' rollouts are scored too.
The statistics are defined in dem/runout_study.py. About 10 minutes on one core.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(ROOT / "config/config.yaml"))
    parser.add_argument("--packings", type=int, default=8)
    parser.add_argument("--reruns", type=int, default=8)
    parser.add_argument("--results", default="results", help="where the DAG keeps a trained GNS (optional)")
    parser.add_argument("--figure", default=None, help="runout of every packing by each method (PNG)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    os.environ["NUMBA_NUM_THREADS"] = str(args.threads)
    import yaml

    from calibration.measured import load_column
    from dem.engines import BUILTIN, simulate_case
    from dem.grid import case_from_row, case_table
    from dem.progress import progress_logger
    from dem.runout_study import compare_methods, markdown_table, plot_methods
    from doe.design import centre_run_id, design_cases, design_from_config
    from pipeline.config import gns_datasets, validate_config

    logging.basicConfig(stream=sys.stderr, level=logging.INFO, format="%(asctime)s %(message)s")

    config = validate_config(
        yaml.safe_load(Path(args.config).read_text()), ROOT / "workflow/schemas/config.schema.yaml"
    )
    started = time.perf_counter()
    cases, models = {}, {}
    for row in case_table(config).values():
        if row["split"] == "test" and row["dataset"] in gns_datasets(config):
            cases[f"{row['dataset']} {row['case_id']}"] = case_from_row(row)
            models[f"{row['dataset']} {row['case_id']}"] = row["dataset"]
    doe = config["doe"]
    design = design_from_config(doe)
    for name in doe["measured"]:
        measured = load_column(ROOT / config["measured"][name])
        centre = design_cases(
            design, measured, size_scale=doe["size_scale"], duration_over_tstar=doe["duration_over_tstar"]
        )[centre_run_id(design)]
        cases[f"DoE {name} centre"] = centre
    trajectories = {label: simulate_case(case, BUILTIN) for label, case in cases.items()}
    rollouts = gns_rollouts(trajectories, models, Path(args.results), args.threads)
    study, curves = compare_methods(
        trajectories,
        n_packings=args.packings,
        n_reruns=args.reruns,
        rollouts=rollouts,
        progress=progress_logger("runout methods: DEM runs"),
    )
    study.update(
        config=str(args.config),
        seconds=round(time.perf_counter() - started, 1),
        load_average=os.getloadavg(),
        gns_scored=sorted(rollouts),
    )
    if args.figure:
        plot_methods(curves, args.figure)
    print(markdown_table(study), file=sys.stderr)
    print(json.dumps(study, indent=1))


def gns_rollouts(trajectories: dict, models: dict, results: Path, threads: int) -> dict:
    """{label: GNS rollout} of the cases whose dataset has a trained model under `results`."""
    import torch

    from gns.dataset import read_metadata
    from gns.rollout import rollout_trajectory
    from gns.simulator import load_simulator

    torch.set_num_threads(threads)
    out, loaded = {}, {}
    for label, dataset in models.items():
        model = results / "gns" / dataset / "train" / "model_best.pt"
        metadata = results / "datasets" / dataset / "metadata.json"
        if not (model.exists() and metadata.exists()):
            continue
        if dataset not in loaded:
            loaded[dataset] = load_simulator(model, read_metadata(metadata))
        rollout = rollout_trajectory(loaded[dataset], trajectories[label], on_invalid="flag")
        if rollout.attrs["rollout_valid"]:
            out[label] = rollout
    return out


if __name__ == "__main__":
    main()
