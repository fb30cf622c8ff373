"""How fast a finished DAG run could have been: its CPU bound and its critical path; prints JSON.

    python benchmarks/dag_bounds.py LOG [--root DIR] [--cores 2] [--target-minutes 30]
                                    [--what-if RULE=THREADS:SECONDS ...]

LOG: the Snakemake log of one run (`.snakemake/log/*.snakemake.log`, or what `bash run.sh main`
printed); DIR: the folder it ran in (the benchmark TSVs are read relative to it). Each job's seconds
are its benchmark file's wall time (`s`) and CPU time; the jobs' inputs and outputs, as the log
lists them, give the DAG's edges. Two lower bounds on the wall time follow, whatever the scheduler:
the CPU bound (the jobs' CPU seconds over the cores) and the critical path (the longest chain of jobs,
each waiting for the outputs of the one before). The work bound, the jobs' wall seconds over the
cores, is printed too: it was these runs' measure before jobs had worker processes, and it lies
above the CPU bound by the jobs' start-up, I/O and waits for a core. A wall-time target, such as the default DAG under
30 minutes on 2 cores, is out of reach on a machine where either bound exceeds it; the path says
which jobs a trim must shorten. A third figure replays the run: a list scheduler with the jobs'
seconds and the priorities the log shows (priority_schedule); where it lands near the real wall
time, the gap between it and the bounds is what the priorities cost, and a change of priorities
can be tried on it before a run. `--what-if` replays the run again with every job of RULE on THREADS
cores for SECONDS each (a thread count measured for that job alone, say), and prints that replay
beside the run's.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
from pathlib import Path

RULE = re.compile(r"^(?:local)?rule (\w+):$")
FIELD = re.compile(r"^\s+(input|output|benchmark|jobid|wildcards|priority|threads): (.*)$")


def parse_jobs(log: Path) -> list[dict]:
    """[{rule, jobid, input [paths], output [paths], benchmark, wildcards, priority, threads}] of the jobs
    the log started (Snakemake writes a job's threads only when more than 1)."""
    jobs, job = [], None
    for line in log.read_text().splitlines():
        match = RULE.match(line)
        if match:
            job = {
                "rule": match.group(1),
                "input": [],
                "output": [],
                "benchmark": None,
                "wildcards": "",
                "priority": 0,
                "threads": 1,
            }
            jobs.append(job)
            continue
        match = FIELD.match(line)
        if job is not None and match:
            key, value = match.groups()
            if key in ("input", "output"):
                job[key] = [p.strip() for p in value.split(",") if p.strip()]
            elif key in ("priority", "threads"):
                job[key] = int(value)
            else:
                job[key] = value.strip()
        elif job is not None and not line.startswith(" "):
            job = None
    return jobs


def job_seconds(path: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one Snakemake benchmark TSV (its first row)."""
    with path.open() as f:
        row = next(csv.DictReader(f, delimiter="\t"))
    cpu = row.get("cpu_time", "NA")
    return float(row["s"]), float(cpu) if cpu not in ("NA", "") else float("nan")


def critical_path(jobs: list[dict]) -> tuple[float, list[dict]]:
    """(seconds, [job]) of the longest chain, each job after the producers of its inputs."""
    producer = {path: k for k, job in enumerate(jobs) for path in job["output"]}
    finish: dict[int, tuple[float, int | None]] = {}

    def finish_of(k: int) -> tuple[float, int | None]:
        if k not in finish:
            before = [(finish_of(producer[p])[0], producer[p]) for p in jobs[k]["input"] if p in producer]
            start, previous = max(before, default=(0.0, None))
            finish[k] = (start + jobs[k]["seconds"], previous)
        return finish[k]

    for k in range(len(jobs)):  # in log order: a producer is started before its consumers
        finish_of(k)
    last = max(finish, key=lambda k: finish[k][0])
    chain, k = [], last
    while k is not None:
        chain.append(jobs[k])
        k = finish[k][1]
    return finish[last][0], chain[::-1]


def priority_schedule(jobs: list[dict], cores: int) -> float:
    """Seconds a list scheduler takes over `jobs` on `cores` cores, each job its `threads` cores
    (default 1) for its seconds: whenever cores are free it starts the ready jobs in order of
    priority (ties: the log's order), each that fits the free cores, as Snakemake's priorities ask;
    a job of more threads than are free waits while lower ones fill them. Above the two bounds by
    the time the priorities leave a core idle while a long chain waits."""
    producer = {path: k for k, job in enumerate(jobs) for path in job["output"]}
    needs = [{producer[p] for p in job["input"] if p in producer and producer[p] != k} for k, job in enumerate(jobs)]
    done, running, clock, free = set(), [], 0.0, cores
    waiting = set(range(len(jobs)))
    while waiting or running:
        ready = sorted((k for k in waiting if needs[k] <= done), key=lambda k: (-jobs[k]["priority"], k))
        for k in ready:
            threads = min(jobs[k].get("threads", 1), cores)
            if threads <= free:
                waiting.discard(k)
                running.append((clock + jobs[k]["seconds"], k, threads))
                free -= threads
        if not running:
            raise ValueError("jobs wait on outputs no job makes")
        running.sort()
        clock, k, threads = running.pop(0)
        done.add(k)
        free += threads
    return clock


def what_if(jobs: list[dict], changes: list[str], cores: int) -> dict:
    """{what_if: {rule: {threads, seconds}}, what_if_schedule_minutes} for changes "RULE=THREADS:SECONDS"
    (each job of RULE), {} for none."""
    if not changes:
        return {}
    changed = {}
    for change in changes:
        match = re.fullmatch(r"(\w+)=(\d+):([0-9.]+)", change)
        if not match:
            raise SystemExit(f"--what-if {change!r}: expected RULE=THREADS:SECONDS, e.g. calibrated_inverse=2:146")
        rule, threads, seconds = match.group(1), int(match.group(2)), float(match.group(3))
        if not any(job["rule"] == rule for job in jobs):
            raise SystemExit(f"--what-if {change!r}: no timed job of rule {rule} in the log")
        changed[rule] = {"threads": threads, "seconds": seconds}
    replayed = [dict(job, **changed.get(job["rule"], {})) for job in jobs]
    return {"what_if": changed, "what_if_schedule_minutes": round(priority_schedule(replayed, cores) / 60, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("log", type=Path)
    parser.add_argument("--root", type=Path, default=Path("."), help="the folder the DAG ran in")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--target-minutes", type=float, default=30.0)
    parser.add_argument(
        "--what-if", action="append", default=[], metavar="RULE=THREADS:SECONDS", help="replay with these jobs changed"
    )
    args = parser.parse_args()
    parsed = parse_jobs(args.log)
    timed = [bool(job["benchmark"]) and (args.root / job["benchmark"]).exists() for job in parsed]
    missing = [job["rule"] for job, ok in zip(parsed, timed) if not ok]
    jobs = [job for job, ok in zip(parsed, timed) if ok]
    if not jobs:
        raise SystemExit(f"{args.log}: no job with a benchmark file under {args.root}")
    for job in jobs:
        job["seconds"], job["cpu_seconds"] = job_seconds(args.root / job["benchmark"])
    work = sum(job["seconds"] for job in jobs)
    cpu = sum(job["cpu_seconds"] for job in jobs if math.isfinite(job["cpu_seconds"]))
    path_seconds, path = critical_path(jobs)
    # the jobs' CPU seconds are the strict bound: a job whose DEM runs have worker processes
    # (dem.run_ahead) holds more than one core for part of its wall time, so its seconds undercount it
    bounds = {"cpu": cpu / args.cores / 60, "critical_path": path_seconds / 60}
    print(
        json.dumps(
            {
                "log": str(args.log),
                "jobs": len(jobs),
                "jobs_without_benchmark": sorted(set(missing)),
                "cores": args.cores,
                "work_job_seconds": round(work, 1),
                "work_cpu_seconds": round(cpu, 1),
                "work_bound_minutes": round(work / args.cores / 60, 1),
                "cpu_bound_minutes": round(bounds["cpu"], 1),
                "critical_path_minutes": round(bounds["critical_path"], 1),
                "lower_bound_minutes": round(max(bounds.values()), 1),
                # the DAG's own priorities with these job times, in place of Snakemake's choices
                "priority_schedule_minutes": round(priority_schedule(jobs, args.cores) / 60, 1),
                **what_if(jobs, args.what_if, args.cores),
                "target_minutes": args.target_minutes,
                "target_reachable": max(bounds.values()) <= args.target_minutes,
                "critical_path": [
                    {"rule": job["rule"], "wildcards": job["wildcards"], "seconds": round(job["seconds"], 1)}
                    for job in path
                ],
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
