"""The finished DEM runs of one long job, kept so that the job, killed and run again, loses only the
run that was in flight.

A job that runs many DEM collapses in one process (a diagnosis, a DoE campaign, a Bayesian
optimisation on DEM, the calibrated model's validations and runoff) opens `kept_runs(folder)` around
its work; the stage layer's job functions do so with `keeps_runs`, the folder beside the job's output
(`runs_folder`). Inside it:

  - dem.engines.simulate_case looks its collapse up by key and returns the stored trajectory, or runs
    it in a work folder inside the store (a killed builtin run resumes from its checkpoint there) and
    stores it;
  - dem.packing.settle_column does the same for a settled packing (about half a collapse's cost).

The key is the sha256 of everything that determines the result (`run_key`): the case's every field
(seed, size_scale and name included), the engine, its version and its config (threads, solvers), the
packing's bits when one is given, and the builtin engine's version (its kernels' source). What is
returned is always the stored file read back (dem.trajectory's one writer and reader), so a run
reused by a rerun gives the very bits, every array and attribute, that the first attempt returned.

A run that raises is not stored: rerun, it fails again as it did, with the same exception. Once the
job's work returns (its outputs written) the folder is removed, so results/ does not grow; after an
exception, or a kill, it stays and a rerun of the same job reuses what it holds. One job per folder;
each file is written atomically (dem.atomic), so whatever lies under a run's name is whole.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import json
import logging
import os
import shutil
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import Executor
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np

from dem.integrate import ENGINE_VERSION
from dem.trajectory import Trajectory, TrajectoryError, read_trajectory, write_trajectory

log = logging.getLogger(__name__)

Job = TypeVar("Job", bound=Callable)
_ACTIVE: ContextVar[RunStore | None] = ContextVar("dem_run_store", default=None)


@dataclass
class RunStore:
    """Stored runs in `folder`: <key>.h5 per finished run, <key>.work/ for the run in flight.
    reused, ran: {kind ("collapse", "packing"): runs read from the store, runs made} in this attempt;
    workers: the processes dem.run_ahead makes runs in for this store, shut down when kept_runs ends."""

    folder: Path
    reused: Counter = field(default_factory=Counter)
    ran: Counter = field(default_factory=Counter)
    workers: Executor | None = field(default=None, repr=False)  # dem.run_ahead's processes, while the block lasts

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.h5"

    def stored(self) -> list[Path]:
        """The finished runs the folder holds (a half-written temporary file is none of them)."""
        return sorted(self.folder.glob("[!.]*.h5")) if self.folder.is_dir() else []

    def kept(
        self,
        key: str,
        run: Callable[[Path], Trajectory],
        progress: Callable[[float], None] | None = None,
        resume_files: tuple[str, ...] = (),
    ) -> Trajectory:
        """The run of `key` (run_key): read from the store, or made by run(work folder) and stored.
        The work folder is emptied first but for `resume_files` (what a killed run resumes from),
        and removed once the run is stored or has raised. progress(1.0) when the run is reused."""
        kind = key.partition("-")[0]
        trajectory = self._read(key)
        if trajectory is not None:
            self.reused[kind] += 1
            log.debug("%s: reused %s", self.folder, key)
            if progress is not None:
                progress(1.0)
            return trajectory
        work = self.folder / f"{key}.work"
        _clear_work_dir(work, resume_files)
        try:
            trajectory = run(work)
        except Exception:  # a failed run is not stored; an interrupt keeps the work folder's checkpoint
            shutil.rmtree(work, ignore_errors=True)
            raise
        write_trajectory(self.path(key), trajectory)
        shutil.rmtree(work, ignore_errors=True)
        self.ran[kind] += 1
        return read_trajectory(self.path(key))

    def _read(self, key: str) -> Trajectory | None:
        path = self.path(key)
        if not path.exists():
            return None
        try:
            return read_trajectory(path)
        except TrajectoryError as exc:  # written atomically, so damaged afterwards: run it again
            log.warning("%s set aside, the run is made again: %s", path, exc)
            path.unlink()
            return None

    def summary(self) -> str:
        """One line for the job's log: the runs reused and made, by kind."""
        return f"DEM runs kept in {self.folder}: reused {_counts(self.reused)}; ran {_counts(self.ran)}"


def active_store() -> RunStore | None:
    """The store of the kept_runs block this code runs in, or None outside any."""
    return _ACTIVE.get()


@contextlib.contextmanager
def kept_runs(folder: str | os.PathLike) -> Iterator[RunStore]:
    """Keep the DEM runs made inside the block in `folder` and reuse those it already holds; the
    folder is removed when the block ends normally, kept when it raises (or the process is killed)."""
    store = RunStore(Path(folder))
    earlier = len(store.stored())
    if earlier:
        log.info(
            "%s: %d run(s) stored by an earlier attempt of this job, reused where asked for", store.folder, earlier
        )
    try:
        with using_store(store):
            yield store
    except BaseException:
        log.info("%s; kept for a rerun", store.summary())
        raise
    finally:
        if store.workers is not None:
            store.workers.shutdown(cancel_futures=True)
            store.workers = None
    log.info("%s; folder removed", store.summary())
    shutil.rmtree(store.folder, ignore_errors=True)


@contextlib.contextmanager
def using_store(store: RunStore) -> Iterator[RunStore]:
    """Make `store` the active one inside the block, leaving its folder as it is afterwards (a worker
    process of dem.run_ahead stores its runs in its job's store this way)."""
    token = _ACTIVE.set(store)
    try:
        yield store
    finally:
        _ACTIVE.reset(token)


def runs_folder(output: str | os.PathLike) -> Path:
    """Where the job writing `output` (a file or a folder) keeps its runs: .<name>.runs beside it."""
    output = Path(os.path.abspath(output))
    return output.with_name(f".{output.name}.runs")


def keeps_runs(output: str) -> Callable[[Job], Job]:
    """Decorate a stage's job function so that it runs inside kept_runs(runs_folder(its argument
    `output`)): the folder is removed when the function returns, its outputs written. The decorated
    function's `keeps_runs_beside` names that argument."""

    def decorate(job: Job) -> Job:
        signature = inspect.signature(job)
        if output not in signature.parameters:
            raise TypeError(f"{job.__qualname__} has no argument {output!r} to keep its DEM runs beside")

        @functools.wraps(job)
        def wrapper(*args, **kwargs):
            with kept_runs(runs_folder(signature.bind(*args, **kwargs).arguments[output])):
                return job(*args, **kwargs)

        wrapper.keeps_runs_beside = output
        return wrapper

    return decorate


# -- keys ----------------------------------------------------------------------------------------------
def run_key(kind: str, **parts: object) -> str:
    """The name of a run in a store, <kind>-<sha256 hex>, from `parts` (JSON-able: case dicts,
    configs, digests) and the builtin engine's version: what determines the run's result."""
    parts = dict(parts, builtin_engine_version=ENGINE_VERSION)
    text = json.dumps(parts, sort_keys=True, default=_plain)
    return f"{kind}-{hashlib.sha256(text.encode()).hexdigest()}"


def trajectory_digest(trajectory: Trajectory | None) -> str | None:
    """sha256 hex of a trajectory's arrays (dtype, shape and bytes) and attributes (as the file holds
    them: None as ""), or None for None: the packing part of a collapse's key."""
    if trajectory is None:
        return None
    digest = hashlib.sha256()
    for array in (trajectory.positions, trajectory.radius, trajectory.particle_type):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.tobytes())
    attrs = {key: "" if value is None else value for key, value in trajectory.attrs.items()}
    digest.update(json.dumps(attrs, sort_keys=True, default=_plain).encode())
    return digest.hexdigest()


def _counts(counter: Counter) -> str:
    return ", ".join(f"{n} {kind}(s)" for kind, n in sorted(counter.items())) or "none"


def _plain(value: object) -> object:
    """A numpy scalar or array as the Python value json writes (as read back from a file)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, bytes):
        return value.decode()
    return str(value)


def _clear_work_dir(work: Path, keep: tuple[str, ...]) -> None:
    """Create `work`, emptied of what a killed run left but for the files named in `keep`."""
    work.mkdir(parents=True, exist_ok=True)
    for path in work.iterdir():
        if path.name in keep and path.is_file():
            log.info("keeping %s: the run resumes from it", path)
        elif path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()
