"""How the runout changes with grain size: one parameter set from coarse grains to real ones; prints JSON.

The column and parameters of --config's scale_ladder section (by default the measured quartz column,
a = 6, L_i = 0.02 m, at (mu, e) = (0.39, 0.54)) are settled and collapsed at each of --scales
(default size_scale 5, 4, 3, 2, 1.5 and 1, real grains), on --packings packings each (seeds
scale_ladder.seed, + 1, ...), --workers runs at a time (one per core), finest first. The runs, their
reading, the summary and the figure are the DAG's (dem/scale_ladder.py; the DAG runs the same ladder as
rule scale_ladder, workflow/rules/scale_ladder.smk): per scale the grains, grains across, L* at
t/t* = 1, 2, 3.5 and 4 and at the last frame (mean, packing scatter, each packing), the final
deposit height over H_i and the cost per run (settle and collapse seconds, particle-steps/s). Runout
read by --config's runout method. --figure writes L*(t/t*) per scale and the final L* and height
against scale.

    python benchmarks/scale_ladder.py [--scales 5,4,3,2,1.5,1] [--packings 2] [--figure PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dem.case import get_material  # noqa: E402
from dem.plots import case_title  # noqa: E402
from dem.runout import RunoutMethod  # noqa: E402
from dem.scale_ladder import LadderRun, case_rows, plot_ladder, read_run, summarise  # noqa: E402


def one_run(row: dict, runout: dict) -> LadderRun:
    """Settle and collapse one packing of the ladder (one thread) and read it as the DAG does."""
    from dem.collapse import simulate_collapse
    from dem.grid import case_from_row
    from dem.packing import settle_column

    case = case_from_row(row)
    start = time.perf_counter()
    packing = settle_column(case)
    settle_s = time.perf_counter() - start
    run = read_run(simulate_collapse(case, packing), runout, settle_s)
    print(f"size_scale {case.size_scale:g} seed {case.seed}: done", file=sys.stderr, flush=True)
    return run


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(ROOT / "config/config.yaml"), help="its scale_ladder and runout")
    parser.add_argument("--scales", default="5,4,3,2,1.5,1")
    parser.add_argument("--packings", type=int, default=2)
    parser.add_argument("--duration", type=float, default=None, help="t* of collapse (default: the config's)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--figure", default=None)
    args = parser.parse_args()
    import yaml

    from pipeline.config import validate_config

    config = validate_config(
        yaml.safe_load(Path(args.config).read_text()), ROOT / "workflow/schemas/config.schema.yaml"
    )
    spec = dict(config["scale_ladder"], size_scales=[float(s) for s in args.scales.split(",")], packings=args.packings)
    if args.duration is not None:
        spec["duration_over_tstar"] = args.duration
    runout = RunoutMethod.from_config(config["runout"])
    rows = sorted(case_rows(spec), key=lambda row: row["size_scale"])  # finest (longest) first
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        runs = list(pool.map(one_run, rows, [runout.to_config()] * len(rows)))
    summary = summarise(runs)
    if args.figure:  # titled as the DAG's figure
        plot_ladder(summary, runs, args.figure, case_title(dict(spec, material=get_material(spec["material"]).name)))
    print(
        json.dumps(
            {
                "benchmark": "scale_ladder",
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "machine": f"{os.cpu_count()} cores, {args.workers} runs at a time",
                "load_average_1min_at_end": round(os.getloadavg()[0], 2),
                "wall_s": round(time.perf_counter() - start, 1),
                "case": {k: spec[k] for k in ("material", "L_i", "aspect_ratio", "friction", "restitution")},
                "duration_over_tstar": spec["duration_over_tstar"],
                "runout_method": runout.label,
                "by_size_scale": summary,
                "figure": args.figure,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
