"""A long job's batch of independent DEM runs made ahead, several at a time, in worker processes.

A job that runs its collapses one after the other (a validation on several packings, the star of a
target-scale correction, predictions across aspect ratios) keeps one core busy. On a machine where
another core is idle (the end of a DAG, where the last answer job runs alone), `run_ahead(cases,
config)` first makes the batch's runs in `workers` processes, each storing its run in the job's
run store (dem.run_store.kept_runs); the job's own loop then reads every run back from the store.
What the job gets is therefore the stored file either way, the same bits as made in turn
(tests/test_run_store.py), and the loop's order, failures and logging are unchanged: a run that
fails in a worker is not stored and fails again, the same way, when the loop asks for it.

The job still holds one core of the scheduler's, so its workers run at a lower priority (nice
WORKER_NICENESS): beside another job they yield to it and the job gets about the one core the
scheduler gave it (a GNS training on the DAG's critical path is not slowed by them), beside an idle
core they use it; the machine's throughput is the same either way. The workers are config
dem.workers, capped by the cores this process may run on (a SLURM job's allocation) and 1 where a
run is itself threaded (dem.threads > 1: threads that wait on each other slow down many times on a
busy core). Outside a run store, or with one worker, it does nothing.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

from dem.engines import FAILURES, collapse_key, failure_reason, get_engine, run_config, simulate_case
from dem.progress import progress_logger
from dem.run_store import RunStore, active_store, using_store

if TYPE_CHECKING:
    from dem.case import CollapseCase

log = logging.getLogger(__name__)

# A worker process's niceness: on a busy core a nice-0 process gets ~90% of the time against it
# (Linux CFS weights 1024 and 110), so the workers take what the scheduled jobs leave.
WORKER_NICENESS = 10


def batch_workers(config: dict | None) -> int:
    """Worker processes for a batch of runs of `config` (the workflow's dem section): its `workers`
    (default 1), at most the cores this process may use, and 1 when a run has several threads."""
    config = config or {}
    if int(config.get("threads", 1)) > 1:
        return 1
    return max(1, min(int(config.get("workers", 1)), len(os.sched_getaffinity(0))))


def run_ahead(cases: Sequence[CollapseCase], config: dict | None, label: str = "runs") -> int:
    """Make the collapses of `cases` (each settled by its own packing step) that the active run store
    lacks, batch_workers(config) at a time in worker processes, into that store. Returns how many
    were made; 0 outside a store or with one worker. A run that fails is left out (logged)."""
    store = active_store()
    workers = batch_workers(config)
    if store is None or workers < 2:
        return 0
    settings = run_config(config)
    engine = get_engine(settings.get("engine", "builtin"), settings)
    todo = {collapse_key(case, config, engine=engine): case for case in cases}
    todo = [case for key, case in todo.items() if not store.path(key).exists()]
    if len(todo) < 2:
        return 0
    started, made = time.perf_counter(), 0
    if store.workers is None:  # started once for the job, ended with its store
        # forked: a spawned worker would import the job's script again as its main module (a
        # Snakemake script runs its job at the top level) and pay the imports (~1 s) once more
        store.workers = ProcessPoolExecutor(
            workers, mp_context=get_context("fork"), initializer=os.nice, initargs=(WORKER_NICENESS,)
        )
    futures = [store.workers.submit(_stored_run, str(store.folder), case, config) for case in todo]
    progress = progress_logger(f"{label}: {len(todo)} runs made ahead on {workers} processes", log)
    for done, future in enumerate(as_completed(futures), 1):
        failed = future.result()
        made += failed is None
        if failed is not None:
            log.info("%s: a run made ahead failed (the job's own call will say how): %s", label, failed)
        progress(done / len(todo))
    log.info("%s: %d run(s) made ahead in %.1f s", label, made, time.perf_counter() - started)
    return made


def _stored_run(folder: str, case: CollapseCase, config: dict | None) -> str | None:
    """One collapse made into the run store at `folder` (in a worker process); None when stored, else
    why it failed. A bug raises, so that the job stops as it would have."""
    with using_store(RunStore(Path(folder))):
        try:
            simulate_case(case, config)
        except FAILURES as exc:
            return failure_reason(exc)
    return None
