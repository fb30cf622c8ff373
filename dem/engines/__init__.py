"""DEM engines behind one interface (dem.engines.base.Engine): builtin, LIGGGHTS, MFIX.

    engine = get_engine(config["dem"]["engine"], config["dem"])   # "auto" | "builtin" | "liggghts" | "mfix"
    trajectory = engine.simulate(case, packing, work_dir, output="case.h5")

`simulate_case(case, config)` runs one case with the configured engine in a scratch folder: every
DEM run of the pipeline goes through here or through the DEM stage's own rules. Inside
dem.run_store.kept_runs (a long job's block) a run made before is read from the store instead, and a
new one is stored there.

A DEM run that fails raises one of FAILURES (a blow-up, a solver that crashed, output that cannot
be read or holds no runout front, a case that cannot be built). A caller that can do without the
run (an optimisation, a design, repeated runs on several packings) catches these, records the run
with `failure_reason(exc)` and never averages it in; any other exception is a bug and propagates.

`config` is the `dem` section of the workflow config; solver paths are configurable under
`solvers`, e.g. {"solvers": {"liggghts": "/usr/bin/liggghts", "mfix": "/opt/mfix/mfixsolver"}};
a solver not configured is looked up on PATH. `auto` picks MFIX where its solver is found, else
LIGGGHTS, else the builtin engine, and logs which and why.
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from typing import TYPE_CHECKING

from dem.case import CaseError
from dem.engines.base import Engine, EngineError, EngineNotInstalled
from dem.engines.builtin import BuiltinEngine
from dem.engines.liggghts import LiggghtsEngine
from dem.engines.mfix import MfixEngine
from dem.integrate import SimulationError
from dem.run_store import active_store, run_key, trajectory_digest
from dem.runout import RunoutError
from dem.trajectory import TrajectoryError

if TYPE_CHECKING:
    from dem.case import CollapseCase
    from dem.trajectory import Trajectory

log = logging.getLogger(__name__)

ENGINES = {"builtin": BuiltinEngine, "liggghts": LiggghtsEngine, "mfix": MfixEngine}
AUTO_ORDER = ("mfix", "liggghts", "builtin")
BUILTIN = {"engine": "builtin"}  # simulate_case's config for runs that need the builtin engine's features
FAILURES = (SimulationError, EngineError, TrajectoryError, RunoutError, CaseError)  # a DEM run that failed

__all__ = [
    "BUILTIN",
    "ENGINES",
    "FAILURES",
    "Engine",
    "EngineError",
    "EngineNotInstalled",
    "collapse_key",
    "failure_reason",
    "get_engine",
    "simulate_case",
    "solver_paths",
]


def failure_reason(exc: BaseException) -> str:
    """How a failed run is recorded: "ExceptionName: message" (the message names the file or step)."""
    return f"{type(exc).__name__}: {exc}"


def solver_paths(config: dict | None) -> dict:
    """{engine name: solver path} from config['solvers'] (missing: {}); unknown names are an error."""
    solvers = dict((config or {}).get("solvers") or {})
    unknown = set(solvers) - set(ENGINES) - {"builtin"}
    if unknown:
        raise EngineError(f"dem.solvers: unknown engine(s) {sorted(unknown)}; known: {sorted(ENGINES)}")
    for name, path in solvers.items():
        if path is not None and not isinstance(path, str):
            raise EngineError(f"dem.solvers.{name}: expected a path (string), got {path!r}")
    return solvers


def get_engine(name: str = "auto", config: dict | None = None) -> Engine:
    """The engine `name` ("auto", "builtin", "liggghts", "mfix"), solver paths from config['solvers'],
    threads per run from config['threads'] (the builtin engine's; the solvers run serially).

    A named solver engine that is not installed raises EngineNotInstalled saying how to install it.
    """
    solvers = solver_paths(config)
    threads = (config or {}).get("threads", 1)
    if name == "auto":
        reasons = []
        for candidate in AUTO_ORDER:
            engine = ENGINES[candidate](solvers.get(candidate), threads)
            ok, why = engine.availability()
            reasons.append(why)
            if ok:
                log.info("dem.engine auto: using %s (%s)", candidate, "; ".join(reasons))
                return engine
        raise EngineError("dem.engine auto: no engine available: " + "; ".join(reasons))  # unreachable: builtin
    if name not in ENGINES:
        raise EngineError(f"dem.engine: unknown engine {name!r}; choose one of auto, {', '.join(ENGINES)}")
    engine = ENGINES[name](solvers.get(name), threads)
    engine.require_solver()
    log.info("dem.engine %s: %s", name, engine.availability()[1])
    return engine


def run_config(config: dict | None) -> dict:
    """What of the dem section a run's result depends on: all of it but `workers` (dem.run_ahead)."""
    return {key: value for key, value in (config or {}).items() if key != "workers"}


def collapse_key(
    case: CollapseCase, config: dict | None, packing: Trajectory | None = None, engine: Engine | None = None
) -> str:
    """The run store's name (dem.run_store.run_key) of simulate_case(case, config, packing)'s run:
    the case, the engine (name, version, config) and the packing's bits."""
    config = run_config(config)
    engine = engine or get_engine(config.get("engine", "builtin"), config)
    return run_key(
        "collapse",
        case=case.to_dict(),
        engine=engine.name,
        engine_version=engine.version(),
        config=config,
        packing=trajectory_digest(packing),
    )


def simulate_case(
    case: CollapseCase,
    config: dict | None = None,
    packing: Trajectory | None = None,
    progress: Callable[[float], None] | None = None,
) -> Trajectory:
    """One collapse of `case` with the engine config["engine"] (the workflow's `dem` section; None or
    no "engine": builtin), from `packing` (None: settled by the builtin settling step), in a scratch
    folder removed afterwards. The trajectory records the engine that ran it.

    Inside dem.run_store.kept_runs: the stored run of the same case, engine (name, version, config)
    and packing bits when there is one (progress(1.0)), else the run made in the store's work folder
    and stored; either way the stored file read back, so that both give the same bits."""
    config = run_config(config)
    engine = get_engine(config.get("engine", "builtin"), config)
    store = active_store()
    if store is None:
        with tempfile.TemporaryDirectory(prefix=f"dem_{engine.name}_") as work_dir:
            return engine.simulate(case, packing, work_dir, progress=progress)
    key = collapse_key(case, config, packing, engine)
    return store.kept(
        key, lambda work_dir: engine.simulate(case, packing, work_dir, progress=progress), progress, engine.resume_files
    )
