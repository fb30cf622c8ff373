"""CPU time of Snakemake's own scheduling over a DAG of jobs that do nothing but wait; prints JSON.

Snakemake (9.x) rate-limits job starts (--max-jobs-per-timespan, default 100/1s) by waking its
scheduler one timespan after every scheduling pass; each pass sets its own timer, and every finished
job starts one more pass, so the wake-ups pile up: ~one pass a second for every job finished so far.
On the default DAG (468 jobs) that kept Snakemake's process at 15-25% of a core by its end, and its
exit waits for the last timer. The project's Snakefile drops the limiter of a local run at its start
(`onstart`, read from the Snakefile here); a longer timespan (1000/10s, the default profile's
setting before) wakes it less often and waits that long at the exit.

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

ROOT = Path(__file__).resolve().parents[1]
SNAKEFILE = """
{hook}
N = {n_jobs}
rule all:
    input: expand("done/{{k}}", k=range(N))
rule wait:
    output: "done/{{k}}"
    shell: "sleep {sleep}; touch {{output}}"
"""


def project_hook() -> str:
    """The project's `onstart:` block, as its Snakefile has it."""
    lines = (ROOT / "Snakefile").read_text().splitlines()
    start = lines.index("onstart:")
    end = next(k for k in range(start + 1, len(lines)) if not lines[k].startswith(" "))
    return "\n".join(lines[start:end])


def run(settings: list[str], n_jobs: int, sleep: float, hook: str = "") -> dict:
    """Wall and CPU seconds of one Snakemake run of the synthetic DAG with the extra `settings`
    (and the Snakefile lines `hook`)."""
    with tempfile.TemporaryDirectory() as folder:
        Path(folder, "Snakefile").write_text(SNAKEFILE.format(hook=hook, n_jobs=n_jobs, sleep=sleep))
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
        "settings": settings + (["(the project's onstart)"] if hook else []),
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 2),
        "cpu_s_per_job": round(cpu / n_jobs, 3),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=120, help="jobs of the synthetic DAG")
    parser.add_argument("--sleep", type=float, default=2.0, help="seconds each job waits")
    args = parser.parse_args()
    runs = {
        "snakemake_default": run([], args.jobs, args.sleep),
        "timespan_10s": run(["--max-jobs-per-timespan", "1000/10s"], args.jobs, args.sleep),
        "project": run([], args.jobs, args.sleep, project_hook()),
    }
    print(
        json.dumps(
            {
                "benchmark": "scheduler_overhead",
                "jobs": args.jobs,
                "sleep_s": args.sleep,
                **runs,
                "cpu_ratio_default_over_project": round(
                    runs["snakemake_default"]["cpu_s"] / max(runs["project"]["cpu_s"], 1e-9), 2
                ),
                "cpus": os.cpu_count(),
                "machine": platform.processor() or platform.machine(),
                "load_average": os.getloadavg()[0],
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
