"""DEM runs over a model's parameter box (the models: calibration/model.py): the builtin DEM that
runs them, and the library of design runs.

The design (`build_library`: a seeded Latin hypercube over each model's box) does not depend on the
measured values, only on the measured columns' geometry and observation points, so one library
serves any number of data sets of the same columns (the hidden-effect tests use this). Every fit is
done on a Gaussian-process emulator of a model's runs (`Library.emulator`, calibration/emulator.py).

Packings: the grains' packing is a random realisation; two packings of the same column give runouts
that differ by several per cent late in the collapse. Design runs cycle through a pool of settled
packings (seeded, settled once per column at settings.reference), so the emulator learns the mean
response (its white-noise term takes the scatter); one run of the base model per packing at the box
centre, and every repeat a diagnosis adds, measure the packing-to-packing scatter that any single
realisation (such as the measured one) carries on top of it (`Library.packing_std`).

A design run that fails (dem.engines.FAILURES) is recorded with its reason in `Library.failed` (saved
with the library) and left out of the runs; a model none of whose runs ran is a LibraryError.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from calibration.emulator import GPEmulator, latin_hypercube
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.observables import LibraryError, Observables
from dem.atomic import atomic_path
from dem.engines import BUILTIN, FAILURES, failure_reason, simulate_case
from dem.packing import settle_column

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from dem.trajectory import Trajectory

log = logging.getLogger(__name__)

FRAMES_PER_TSTAR = 25  # output frames per t*: the measured t/t* are interpolated between them
# The diagnosis runs the builtin engine (BUILTIN) whatever dem.engine says: the candidate mechanisms
# (rolling resistance, cohesion, basal and side-wall friction, gate lift) are its features.


# -- how the DEM runs -----------------------------------------------------------------------------
@dataclass(frozen=True)
class SimulationSettings:
    """How the DEM is run for the diagnosis (builtin engine)."""

    size_scale: float = 4.0  # coarse-graining factor of the grains
    packing_seeds: tuple[int, ...] = (101, 102, 103)
    reference: tuple[float, float] = (0.6, 0.6)  # (mu, e) the packings are settled with

    def duration_for(self, column: MeasuredColumn) -> float:
        """Simulated t/t*: up to the frame at or after the last measured t/t* (runout, or the profile's reading)."""
        last = max(float(column.t_over_tstar[-1]), column.profile_time if column.profile_x is not None else 0.0)
        return float(np.ceil(last * FRAMES_PER_TSTAR - 1e-9) / FRAMES_PER_TSTAR)

    def to_dict(self) -> dict:
        return {
            "size_scale": self.size_scale,
            "packing_seeds": list(self.packing_seeds),
            "reference": list(self.reference),
        }


class DEMRunner:
    """Runs the builtin DEM for `observables`' columns on a pool of settled packings.

    Packing j of every column is settled once (lazily) at settings.reference with seed
    settings.packing_seeds[j]; every run starts from one of them.
    """

    def __init__(self, observables: Observables, settings: SimulationSettings):
        self.observables = observables
        self.settings = settings
        self._packings = {}

    def packing(self, column_index: int, packing_index: int) -> Trajectory:
        """The settled packing `packing_index` of column `column_index` (one-frame Trajectory)."""
        key = (column_index, packing_index)
        if key not in self._packings:
            column = self.observables.columns[column_index]
            case = Model().case(
                column, self.settings.reference, self.settings, self.settings.packing_seeds[packing_index]
            )
            self._packings[key] = settle_column(case)
            log.info(
                "settled %s, packing seed %d: %d grains",
                column.name,
                self.settings.packing_seeds[packing_index],
                case.n_particles,
            )
        return self._packings[key]

    def trajectories(
        self,
        model: Model,
        theta: Sequence[float] | np.ndarray,
        packing_index: int,
        columns: Sequence[int] | None = None,
    ) -> list[Trajectory]:
        """One collapse per column (or per column index in `columns`) of `model` at theta [p] on
        packing `packing_index`."""
        out = []
        for c in range(len(self.observables.columns)) if columns is None else columns:
            column = self.observables.columns[c]
            case = model.case(column, theta, self.settings, self.settings.packing_seeds[packing_index])
            out.append(simulate_case(case, BUILTIN, packing=self.packing(c, packing_index)))
        return out

    def observe(
        self,
        model: Model,
        theta: Sequence[float] | np.ndarray,
        packing_index: int,
        columns: Sequence[int] | None = None,
    ) -> np.ndarray:
        """Observables of `model` at theta [p] on packing `packing_index`: [q], or only the outputs
        of the column indices in `columns`."""
        return self.observables.from_trajectories(self.trajectories(model, theta, packing_index, columns), columns)


# -- the library of design runs -------------------------------------------------------------------
STAGES = ("design", "replicate", "refine")


@dataclass
class DesignRuns:
    """DEM runs of one model: theta [n, p], observed [n, q], packing index [n], wall seconds [n],
    stage [n]: "design" (Latin hypercube), "replicate" (base model at the box centre, one per
    packing) or "refine" (added by a diagnosis at its current optimum)."""

    model: str
    theta: np.ndarray
    observed: np.ndarray
    packing: np.ndarray
    seconds: np.ndarray
    stage: np.ndarray

    def append(self, theta: ArrayLike, observed: ArrayLike, packing: ArrayLike, seconds: ArrayLike, stage: str) -> None:
        """Append runs: theta [p] or [n, p], observed [q] or [n, q], packing index (one or [n]) and
        wall seconds (one or [n]), all of stage `stage`."""
        if stage not in STAGES:
            raise LibraryError(f"run stage {stage!r} is not one of {STAGES}")
        self.theta = np.vstack([self.theta, np.atleast_2d(theta)])
        self.observed = np.vstack([self.observed, np.atleast_2d(observed)])
        self.packing = np.append(self.packing, packing)
        self.seconds = np.append(self.seconds, seconds)
        self.stage = np.append(self.stage, np.full(np.size(packing), stage))


@dataclass
class Library:
    """Design runs of every model for one set of observables and simulation settings."""

    signature: dict  # Observables.signature() it was built for
    settings: dict
    runs: dict  # model name -> DesignRuns
    _emulators: dict = field(default_factory=dict, repr=False)
    failed: list = field(default_factory=list)  # design runs that failed: {model, parameters, packing, reason}

    def check(self, observables: Observables, models: Iterable[Model]) -> None:
        if json.loads(json.dumps(observables.signature())) != json.loads(json.dumps(self.signature)):
            raise LibraryError(
                "the run library was built for other columns, observation points or runout "
                f"method (columns {[c[0] for c in self.signature['columns']]}, runout "
                f"{self.signature.get('runout', 'not recorded')!r}, columns read otherwise "
                f"{self.signature.get('runout_methods', {})!r}; asked for {observables.runout.to_config()!r}, "
                f"columns read otherwise {observables.stated_methods!r}); rebuild it"
            )
        missing = [m.name for m in models if m.name not in self.runs]
        if missing:
            raise LibraryError(f"the run library has no runs of model(s) {missing}; it holds {list(self.runs)}")

    def restricted(self, observables: Observables) -> Library:
        """This library's runs read at fewer outputs: those of `observables`, whose columns, runout
        method and profile reading must be this library's and whose observation points must be a
        subset of its points. A profile read at fewer x is the same runs read fewer times, so no DEM
        run is repeated (used to compare a diagnosis at two profile resolutions)."""
        wanted = json.loads(json.dumps(observables.signature()))
        mine = json.loads(json.dumps(self.signature))
        labels = [tuple(label) for label in mine["labels"]]
        same = {k: v for k, v in wanted.items() if k != "labels"} == {k: v for k, v in mine.items() if k != "labels"}
        missing = [label for label in wanted["labels"] if tuple(label) not in labels]
        if not same or missing:
            raise LibraryError(
                "a library can be read at a subset of its own outputs only "
                + (f"(not at {missing[:3]}...)" if missing else "(same columns, runout method and profile reading)")
            )
        index = [labels.index(tuple(label)) for label in wanted["labels"]]
        runs = {
            name: DesignRuns(r.model, r.theta.copy(), r.observed[:, index], r.packing.copy(), r.seconds.copy(), r.stage)
            for name, r in self.runs.items()
        }
        return Library(wanted, dict(self.settings), runs, failed=list(self.failed))

    def copy(self) -> Library:
        """An independent copy (runs copied; fitted emulators shared until a model gets new runs)."""
        runs = {
            name: DesignRuns(
                r.model, r.theta.copy(), r.observed.copy(), r.packing.copy(), r.seconds.copy(), r.stage.copy()
            )
            for name, r in self.runs.items()
        }
        return Library(self.signature, dict(self.settings), runs, dict(self._emulators), list(self.failed))

    def training_set(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """(theta [n, p], observed [n, q]) to emulate `model`: its own runs plus the base model's
        design and replicate runs (where the mechanism is off). Base runs added by a refinement stay
        with the base model: they would tell an extension nothing new near its own optimum."""
        base = self.runs["base"]
        if model.mechanism is None:
            return base.theta, base.observed
        shared = base.stage != "refine"
        own = self.runs[model.name]
        return (
            np.concatenate([model.embed_base(base.theta[shared]), own.theta]),
            np.concatenate([base.observed[shared], own.observed]),
        )

    def emulator(self, model: Model, seed: int = 0) -> GPEmulator:
        """The fitted emulator of `model` (cached: it depends on the runs only, not on any data)."""
        key = (model.name, seed)
        previous = self._emulators.get(key)
        theta, observed = self.training_set(model)
        if previous is None or len(previous.train_u) != len(theta):
            started = time.perf_counter()
            self._emulators[key] = GPEmulator(model.box, seed=seed).fit(theta, observed, previous=previous)
            log.info(
                "emulator of %s fitted on %d runs in %.1f s", model.name, len(theta), time.perf_counter() - started
            )
        return self._emulators[key]

    def add_runs(
        self,
        model: Model,
        theta: ArrayLike,
        observed: ArrayLike,
        packing: ArrayLike,
        seconds: ArrayLike,
        stage: str = "refine",
    ) -> None:
        """Append runs of `model` (its emulator is refitted, warm-started, on next use): theta [p]
        or [n, p], observed [q] or [n, q], packing index (one or [n]), wall seconds (one or [n])."""
        self.runs[model.name].append(theta, observed, packing, seconds, stage)

    def packing_std(self) -> np.ndarray:
        """[q] packing-to-packing scatter of one realisation, pooled over every group of runs of
        one model at one parameter point on different packings: the base replicates at the box
        centre, and the repeated runs a diagnosis adds at its optima (so the estimate follows the
        scatter where the fits are made, not only at the centre).

        The pooled variance (few dof per group) is smoothed: over neighbouring runout points of the
        same column, and over all deposit-profile points of a column (the surface roughness of a
        deposit is about the same everywhere along it).
        """
        groups = {}
        for name, runs in self.runs.items():
            for theta, observed, packing in zip(runs.theta, runs.observed, runs.packing):
                # one run per packing: a repeat on the same packing is the same run (deterministic)
                groups.setdefault((name, tuple(np.round(theta, 12))), {})[int(packing)] = observed
        squares, dof = 0.0, 0
        for members in groups.values():
            if len(members) > 1:
                members = np.array(list(members.values()))
                squares = squares + np.sum((members - members.mean(axis=0)) ** 2, axis=0)
                dof += len(members) - 1
        if dof < 1:
            raise LibraryError("the run library has no repeated runs on different packings: no packing scatter")
        variance = squares / dof
        labels = [(label[0], label[1]) for label in self.signature["labels"]]
        smoothed = variance.copy()
        for k, (column, kind) in enumerate(labels):
            if kind == "profile":
                near = [j for j, other in enumerate(labels) if other == (column, kind)]
            else:
                near = [j for j in (k - 1, k, k + 1) if 0 <= j < len(labels) and labels[j] == labels[k]]
            smoothed[k] = variance[near].mean()
        return np.sqrt(smoothed)

    def save(self, path: str | os.PathLike) -> None:
        arrays = {
            "meta": np.array(
                json.dumps(
                    {
                        "signature": self.signature,
                        "settings": self.settings,
                        "models": list(self.runs),
                        "failed": self.failed,
                    }
                )
            )
        }
        for name, runs in self.runs.items():
            for key in ("theta", "observed", "packing", "seconds", "stage"):
                arrays[f"{name}/{key}"] = getattr(runs, key)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                np.savez(handle, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Library:
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            runs = {
                name: DesignRuns(
                    name, *(data[f"{name}/{key}"] for key in ("theta", "observed", "packing", "seconds", "stage"))
                )
                for name in meta["models"]
            }
        return cls(meta["signature"], meta["settings"], runs, failed=meta.get("failed", []))


def build_library(
    observables: Observables,
    models: Iterable[Model],
    settings: SimulationSettings,
    n_base: int = 10,
    n_per_mechanism: int = 8,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
) -> Library:
    """DEM design runs of every model (the first must be the base model).

    Base: `n_base` Latin-hypercube points over (mu, e) plus one run per packing at the box centre
    (the replicates). Each extension: `n_per_mechanism` Latin-hypercube points over its 3-D box
    (its emulator also uses the base runs, where the mechanism is off). Packings cycle over the
    pool. progress: callable(fraction_done) or None.
    """
    models = list(models)
    if not models or models[0].mechanism is not None:
        raise LibraryError("the first model of a run library must be the base model")
    if n_base < 3 or n_per_mechanism < 2:
        raise LibraryError(f"too few design runs (n_base = {n_base} >= 3, n_per_mechanism = {n_per_mechanism} >= 2)")
    n_packings = len(settings.packing_seeds)
    if n_packings < 2:
        raise LibraryError("need at least 2 packing seeds (the packing scatter is measured from them)")
    plans = []
    for k, model in enumerate(models):
        n = n_base if model.mechanism is None else n_per_mechanism
        theta = latin_hypercube(model.box, n, seed + 7919 * k)
        stage = np.full(n, "design")
        if model.mechanism is None:
            centre = model.box.centre
            theta = np.vstack([theta, np.tile(centre, (n_packings, 1))])
            stage = np.concatenate([stage, np.full(n_packings, "replicate")])
        packing = np.arange(len(theta)) % n_packings
        plans.append((model, theta, packing, stage))
    total = sum(len(p[1]) for p in plans)
    started = time.perf_counter()
    runner = DEMRunner(observables, settings)
    runs, done, failed = {}, 0, []
    for model, theta, packing, stage in plans:
        observed, seconds, ran = [], [], []
        for point, index in zip(theta, packing):
            t0 = time.perf_counter()
            done += 1
            where = ", ".join(f"{n}={v:.3g}" for n, v in zip(model.parameter_names, point))
            try:
                observed.append(runner.observe(model, point, int(index)))
                seconds.append(time.perf_counter() - t0)
                ran.append(True)
                log.info("library run %d/%d: %s %s (%.1f s)", done, total, model.name, where, seconds[-1])
            except FAILURES as exc:  # recorded with its reason, left out of the library
                parameters = dict(zip(model.parameter_names, map(float, point)))
                reason = failure_reason(exc)
                failed.append({"model": model.name, "parameters": parameters, "packing": int(index), "reason": reason})
                ran.append(False)
                log.warning("library run %d/%d: %s %s failed, left out: %s", done, total, model.name, where, reason)
            if progress is not None:
                progress(done / total)
        if not any(ran):
            raise LibraryError(
                f"every design run of {model.name} failed: "
                + "; ".join(f"{f['parameters']}: {f['reason']}" for f in failed if f["model"] == model.name)
            )
        ran = np.array(ran)
        runs[model.name] = DesignRuns(
            model.name, theta[ran], np.array(observed), packing[ran], np.array(seconds), stage[ran]
        )
    log.info(
        "library: %d DEM runs x %d columns in %.0f s (%d failed)",
        total,
        len(observables.columns),
        time.perf_counter() - started,
        len(failed),
    )
    return Library(observables.signature(), settings.to_dict(), runs, failed=failed)
