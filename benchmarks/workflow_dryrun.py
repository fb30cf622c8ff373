"""Time of a Snakemake dry run of the paper's 700-case config; prints JSON.

Target: under 30 s. Reports wall time and the CPU time of the Snakemake process (user +
system), which does not grow when other work shares the machine.

    python benchmarks/workflow_dryrun.py [--configfile config/paper.yaml]
"""

import argparse
import json
import os
import platform
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 30.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configfile", default="config/paper.yaml")
    args = parser.parse_args()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "--quiet", "rules", "--configfile", args.configfile],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.exit(f"dry run failed:\n{proc.stderr[-3000:]}")
    total = re.search(r"^total\s+(\d+)", proc.stdout, re.M)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    print(
        json.dumps(
            {
                "benchmark": "workflow_dryrun",
                "configfile": args.configfile,
                "jobs": int(total[1]) if total else None,
                "wall_s": round(wall, 2),
                "cpu_s": round(cpu, 2),
                "target_s": TARGET_S,
                "meets_target": wall < TARGET_S,
                "load_average_1min": os.getloadavg()[0],
                "cpus": os.cpu_count(),
                "python": platform.python_version(),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
