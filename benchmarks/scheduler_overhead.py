"""CPU time of Snakemake's own scheduling over a DAG of jobs that do nothing but wait; prints JSON.

Snakemake (9.x) rate-limits job starts (--max-jobs-per-timespan, default 100/1s) by waking its
scheduler one timespan after every scheduling pass; each pass sets its own timer, and every finished
job starts one more pass, so the wake-ups pile up: ~one pass a second for every job finished so far.
On the default DAG (468 jobs) that kept Snakemake's process at 15-25% of a core by its end. The
default profile (workflow/profiles/default) sets the same rate over a longer timespan.

Each setting runs the same synthetic DAG (n_jobs independent jobs of `sleep`, on 2 cores, feeding
one target) in its own folder; the CPU-seconds are Snakemake's and its children's (the ILP
solver, the shells; the sleeps cost none), so the difference between settings is the scheduler's.

    python benchmarks/scheduler_overhead.py [--jobs 120] [--sleep 2]
"""

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "workflow" / "profiles" / "default" / "config.yaml"
SNAKEFILE = """
N = {n_jobs}
rule all:
    input: expand("done/{{k}}", k=range(N))
rule wait:
    output: "done/{{k}}"
    shell: "sleep {sleep}; touch {{output}}"
"""


def run(settings: list[str], n_jobs: int, sleep: float) -> dict:
    """Wall and CPU seconds of one Snakemake run of the synthetic DAG with the extra `settings`."""
    with tempfile.TemporaryDirectory() as folder:
        Path(folder, "Snakefile").write_text(SNAKEFILE.format(n_jobs=n_jobs, sleep=sleep))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "snakemake", "--cores", "2", "--quiet", "all", *settings],
            cwd=folder,
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.exit(f"snakemake {' '.join(settings)} failed:\n{proc.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "settings": settings,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 2),
        "cpu_s_per_job": round(cpu / n_jobs, 3),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=120, help="jobs of the synthetic DAG")
    parser.add_argument("--sleep", type=float, default=2.0, help="seconds each job waits")
    args = parser.parse_args()
    profile = yaml.safe_load(PROFILE.read_text())["max-jobs-per-timespan"]
    runs = [run([], args.jobs, args.sleep), run(["--max-jobs-per-timespan", profile], args.jobs, args.sleep)]
    print(
        json.dumps(
            {
                "benchmark": "scheduler_overhead",
                "jobs": args.jobs,
                "sleep_s": args.sleep,
                "snakemake_default": runs[0],
                "profile": runs[1],
                "cpu_ratio": round(runs[0]["cpu_s"] / max(runs[1]["cpu_s"], 1e-9), 2),
                "cpus": os.cpu_count(),
                "machine": platform.processor() or platform.machine(),
                "load_average": os.getloadavg()[0],
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
