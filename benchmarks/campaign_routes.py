"""One synthetic campaign through the DAG by every campaign route, the GNS route included, at a GNS
size of one's choosing; prints JSON.

    python benchmarks/campaign_routes.py [--csv data/test/tiny_campaign.csv | --liggghts-seed 0]
        [--gns-cases 30] [--gns-steps 4000] [--budget 20] [--gns-budget 40] [--geometry 1,2,4,6]
        [--out FOLDER]

benchmarks/campaigns.py runs the DoE and the BO on DEM alone (the GNS route needs a GNS dataset and
a training, which the DAG's rules make). This one copies the workflow into --out and runs
config/tiny_all.yaml's diagnosis (rolling resistance its one candidate, size_scale 4) and the
campaign stage on the CSV (default: data/test/tiny_campaign.csv, quartz a = 1, 2, 4 made by the
builtin DEM with hidden rolling resistance 0.15, noise 0.05; --liggghts-seed: instead a campaign of
the same columns made by LIGGGHTS, a truth with rolling resistance drawn from that seed, its own
packing and the lab's runout reading, noise 0.05), with the BO budgets, the campaign's
GNS dataset of --gns-cases runs and its GNS (32 wide for the base settings, calibration's 48 wide,
M = 3, --gns-steps steps) given here. --geometry gives the dataset's aspect ratios by hand
(calibration.campaign_geometry, at the CSV's one L_i, simulated to the longest column's last
measured t/t*). Per route: the optimum, the validated MSE per column and the campaign's, each
column predicted from the others against its scatter bound, the DEM runs and seconds of the
calibration (the GNS route: its dataset's runs and training apart), and what an added column costs;
and the DAG's wall time and job seconds per rule (its benchmark files).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calibration.design_runs import SimulationSettings  # noqa: E402
from calibration.measured import read_measured  # noqa: E402
from calibration.mechanisms import get_mechanisms  # noqa: E402
from calibration.synthetic import draw_truth, liggghts_measurement, synthetic_columns, write_measured_csv  # noqa: E402
from pipeline.benchmarks import read_benchmarks  # noqa: E402
from pipeline.campaign import CampaignResult  # noqa: E402


def copy_workflow(dest: Path) -> None:
    """The Snakefile, workflow, configs and data in `dest` (modification times kept)."""
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy2(ROOT / "Snakefile", dest / "Snakefile")
    for folder in ("workflow", "config", "data"):
        shutil.copytree(ROOT / folder, dest / folder, ignore=shutil.ignore_patterns("__pycache__"), dirs_exist_ok=True)


def job_seconds(folder: Path) -> dict[str, float]:
    """{rule: summed wall seconds of its jobs} from the DAG's benchmark files under `folder`."""
    return {t.rule: t.total_s for t in sorted(read_benchmarks(folder), key=lambda t: t.rule)}


def liggghts_campaign(seed: int, out: Path) -> Path:
    """The tiny campaign's columns (quartz a = 1, 2, 4, L_i 10 mm, t/t* to 3, size_scale 4) made by
    LIGGGHTS under a truth with rolling resistance drawn from `seed`, noise 0.05 in L*, written to
    out/liggghts_campaign.csv (the truth in its comment)."""
    rng = np.random.default_rng(seed)
    mechanism = get_mechanisms(["rolling_resistance"])[0]
    truth = draw_truth(rng, mechanism)
    template = list(read_measured(ROOT / "data/test/tiny_campaign.csv").values())
    a = [c.aspect_ratio for c in template]
    columns = synthetic_columns("quartz", template[0].L_i, a, template[0].t_over_tstar, profile_step_diameters=None)
    columns = [replace(c, name=f"campaign_a{c.aspect_ratio:g}") for c in columns]
    settings = SimulationSettings(size_scale=4.0)
    measured, _ = liggghts_measurement(truth, columns, [mechanism], settings, 0.05, 0.001, rng)
    path = out / "liggghts_campaign.csv"
    write_measured_csv(measured, path, f"made by LIGGGHTS at size_scale 4, truth {truth.to_dict()}, noise 0.05")
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--csv", type=Path, default=ROOT / "data/test/tiny_campaign.csv")
    parser.add_argument("--liggghts-seed", type=int, default=None, help="make the campaign by LIGGGHTS instead")
    parser.add_argument("--gns-cases", type=int, default=30)
    parser.add_argument("--gns-steps", type=int, default=4000)
    parser.add_argument("--budget", type=int, default=20, help="BO on DEM points (one run per column each)")
    parser.add_argument("--gns-budget", type=int, default=40, help="BO on the GNS points (one rollout per column)")
    parser.add_argument("--geometry", default="", help="aspect ratios of the GNS dataset, given by hand")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("/tmp/campaign_routes"))
    args = parser.parse_args()
    copy_workflow(args.out)
    csv_path = args.csv.resolve() if args.liggghts_seed is None else liggghts_campaign(args.liggghts_seed, args.out)
    columns = list(read_measured(csv_path).values())
    calibration = (
        f"budget: {args.budget}, n_initial: 6, gns_budget: {args.gns_budget}, gns_n_initial: 10, "
        f"gns_cases: {args.gns_cases}, gns_splits: {{train: 0.8, valid: 0.1, test: 0.1}}, "
        f"gns_steps: {args.gns_steps}, gns_latent_size: 48, validation_packings: 4"
    )
    if args.geometry:
        duration = math.ceil(2 * max(c.t_over_tstar[-1] for c in columns)) / 2  # t*, the longest column's
        calibration += (
            f", campaign_geometry: {{lab: {{aspect_ratio: [{args.geometry}], L_i: [{columns[0].L_i}], "
            f"duration_over_tstar: {duration}}}}}"
        )
    gns = (
        f"latent_size: 32, n_message_passing: 3, steps: {args.gns_steps}, validate_every: 1000, "
        "validation_windows: 8, validation_rollouts: 3, checkpoint_every: 1000, log_every: 100"
    )
    command = [
        sys.executable,
        "-m",
        "snakemake",
        "--configfile",
        "config/tiny_all.yaml",
        "--profile",
        "workflow/profiles/default",
        "--cores",
        str(args.cores),
        "--config",
        f"measured={{tiny: data/test/tiny_quartz_a2.csv, lab: {csv_path}}}",
        f"calibration={{{calibration}}}",
        f"gns={{{gns}}}",
        "--",
        "results/campaign/lab/campaign.json",
        "results/report/campaign.md",
    ]
    environment = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    started = time.perf_counter()
    with open(args.out / "snakemake.log", "w") as log:
        subprocess.run(command, cwd=args.out, check=True, stdout=log, stderr=subprocess.STDOUT, env=environment)
    wall = time.perf_counter() - started
    result = CampaignResult.read(args.out / "results/campaign/lab/campaign.json")
    out = {
        "settings": {k: str(v) for k, v in vars(args).items()},
        "columns": {c.name: {"aspect_ratio": c.aspect_ratio, "L_i": c.L_i} for c in columns},
        "model": result.routes[0].model,
        "answer": result.answer,
        "routes": [route.summary() for route in result.routes],
        "dag_wall_seconds": wall,
        "job_seconds": job_seconds(args.out / "results/benchmarks"),
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
