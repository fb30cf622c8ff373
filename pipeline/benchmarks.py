"""Snakemake `benchmark:` files, read in one place: the report's time per stage and every stage's
"time spent" (the DoE's DEM jobs, each calibration route's jobs in the comparison).

A benchmark file is a TSV with one row per run of the job (column `s`: wall seconds, `max_rss`:
peak memory in MB). By convention (workflow/rules/common.smk) it lies at
results/benchmarks/<stage>/<rule>[/<wildcards>].tsv.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path


def read_benchmark(path: str | os.PathLike) -> list[dict]:
    """The rows of one benchmark file; ValueError naming the file when it is not one."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    if not rows or "s" not in rows[0]:
        raise ValueError(f"{path}: not a Snakemake benchmark file (no 's' column)")
    return rows


def benchmark_seconds(paths: Iterable[str | os.PathLike]) -> tuple[float, int]:
    """(total wall seconds, jobs) over the benchmark files among `paths` that exist."""
    total, jobs = 0.0, 0
    for path in map(Path, paths):
        if path.is_file():
            for row in read_benchmark(path):
                total += float(row["s"])
                jobs += 1
    return total, jobs


@dataclass
class StageTime:
    """Wall time of one rule's jobs: count, total/mean/max seconds, peak resident memory (MB)."""

    stage: str
    rule: str
    jobs: int
    total_s: float
    max_s: float
    max_rss_mb: float | None

    @property
    def mean_s(self) -> float:
        return self.total_s / self.jobs


def read_benchmarks(benchmark_dir: str | os.PathLike) -> list[StageTime]:
    """One StageTime per <stage>/<rule> under `benchmark_dir` (a missing folder gives [])."""
    groups: dict[tuple[str, str], list[tuple[float, float | None]]] = {}
    root = Path(benchmark_dir)
    for path in sorted(root.rglob("*.tsv")):
        parts = path.relative_to(root).parts
        if len(parts) < 2:
            raise ValueError(f"{path}: benchmark files go in <stage>/<rule>[/...].tsv under {root}")
        rule = parts[1].removesuffix(".tsv")
        for row in read_benchmark(path):  # one row per repeat of a `repeat()` benchmark
            rss = row.get("max_rss", "NA")
            groups.setdefault((parts[0], rule), []).append(
                (float(row["s"]), None if rss in ("NA", "-", "") else float(rss))
            )
    out = []
    for (stage, rule), values in sorted(groups.items()):
        seconds = [s for s, _ in values]
        rss = [r for _, r in values if r is not None]
        out.append(StageTime(stage, rule, len(values), sum(seconds), max(seconds), max(rss) if rss else None))
    return out
