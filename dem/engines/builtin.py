"""The builtin engine (dem.collapse.simulate_collapse) behind the engine interface.

Its "deck" is case.json (the case) beside packing.h5 (the settled packing); running it integrates
in this process and writes trajectory.h5 and a log (builtin.log) into the same folder.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

from dem.atomic import write_text
from dem.case import CollapseCase
from dem.engines.base import MECHANISMS, Engine, EngineError, read_error
from dem.trajectory import Trajectory, TrajectoryError, read_trajectory, write_trajectory

DECK = "case.json"
PACKING = "packing.h5"
OUTPUT = "trajectory.h5"
LOG = "builtin.log"
CHECKPOINT = "checkpoint.npz"  # a long run's state; a rerun resumes from it (dem.collapse)


class BuiltinEngine(Engine):
    name = "builtin"
    mechanisms = MECHANISMS  # it runs every candidate mechanism
    resume_files = (CHECKPOINT,)
    install_hint = "The builtin engine is part of this package (dem.collapse)."

    def availability(self) -> tuple[bool, str]:
        return True, "builtin: always available (dem.collapse, numba)"

    def require_solver(self) -> str:
        return "dem.collapse.simulate_collapse"

    def version(self) -> str:
        from dem.integrate import ENGINE_VERSION

        return ENGINE_VERSION

    def render(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Path:
        work_dir = Path(work_dir)
        write_trajectory(work_dir / PACKING, packing)
        deck = work_dir / DECK
        write_text(deck, json.dumps({"case": case.to_dict(), "packing": PACKING}, indent=2) + "\n")
        return deck

    def run(self, deck: Path, progress: Callable[[float], None] | None = None) -> None:
        from dem.collapse import simulate_collapse
        from dem.integrate import usable_threads

        deck = Path(deck)
        log_path = deck.parent / LOG
        handler = logging.FileHandler(log_path, mode="w")
        logger = logging.getLogger(f"dem.engines.builtin.{deck.parent.name}")
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        # the run's own log file, like a solver's: not repeated into the caller's log, where a
        # diagnosis or a runout study runs hundreds of cases (callers report progress themselves)
        logger.propagate = False
        try:
            spec = json.loads(deck.read_text())
            case = CollapseCase.from_dict(spec["case"])
            packing = read_trajectory(deck.parent / spec["packing"])
            logger.info(
                "builtin engine %s: case %s, %d grains, %d frames, %d thread(s)",
                self.version(),
                case.name,
                case.n_particles,
                case.n_frames,
                self.threads,
            )
            last = [0.0]

            def report(fraction):
                if fraction - last[0] >= 0.1 or fraction >= 1.0:
                    last[0] = fraction
                    logger.info("%3.0f%% done", 100 * fraction)
                if progress is not None:
                    progress(fraction)

            t0 = time.perf_counter()
            trajectory = simulate_collapse(
                case,
                packing,
                progress=report,
                threads=usable_threads(self.threads),
                checkpoint=deck.parent / CHECKPOINT,
            )
            if trajectory.attrs["resumed_from_frame"]:
                logger.info("resumed from the checkpoint at frame %d", trajectory.attrs["resumed_from_frame"])
            logger.info(
                "done in %.1f s (%.3g particle-steps/s)",
                time.perf_counter() - t0,
                trajectory.attrs.get("particle_steps_per_second", float("nan")),
            )
            write_trajectory(deck.parent / OUTPUT, trajectory)
        except Exception as exc:
            logger.error("%s: %s", type(exc).__name__, exc)
            raise EngineError(f"builtin engine failed on deck {deck}: {exc}") from exc
        finally:
            logger.removeHandler(handler)
            handler.close()

    def read(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Trajectory:
        path = Path(work_dir) / OUTPUT
        try:
            trajectory = read_trajectory(path)
        except TrajectoryError as exc:
            raise read_error(path, str(exc)) from exc
        if trajectory.n_frames != case.n_frames or trajectory.n_particles != case.n_particles:
            raise read_error(
                path,
                f"{trajectory.n_frames} frames of {trajectory.n_particles} grains, the case "
                f"needs {case.n_frames} of {case.n_particles}",
            )
        return trajectory
