"""The DEM stage (workflow/rules/dem.smk): one job per case and step, outputs under
results/dem/<dataset>/.

    case-table row -> deck JSON (write_deck) -> settled packing, a one-frame trajectory HDF5
    (settle) -> collapse run with the configured engine, trajectory HDF5 (run_case) -> figure
    (draw_case)

The settled packing comes from the builtin settling step for every engine, so all engines start
from the same grains; run_case hands it to the engine named by config dem.engine (dem.engines).
Every output is written atomically; progress goes to the job's log.
"""

from __future__ import annotations

import logging
import math
import shutil
import time
from pathlib import Path

from dem import grid
from dem.atomic import StrPath
from dem.case import CollapseCase
from dem.engines import get_engine
from dem.integrate import frame_steps, usable_threads
from dem.packing import settle_column, settle_time_step
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from dem.trajectory import Trajectory, read_trajectory, write_trajectory

log = logging.getLogger(__name__)

# What a DEM job asks a cluster for (workflow/profiles/slurm): its particle-steps at a throughput
# below any measured here (builtin 2-4e7 per thread, LIGGGHTS 0.8-0.9e7: benchmarks/builtin_engine.py),
# doubled on each retry; memory for a few copies of its frames on top of the interpreter's.
REQUEST_PARTICLE_STEPS_PER_S = 5e6
SETTLE_TSTAR_REQUESTED = 4.0  # a settle takes ~1.7 t* (dem.packing)
BASE_MEMORY_MB = 1000  # a DEM process with numba and h5py loaded
MIN_RUNTIME_MIN = 10


def write_deck(row: dict, path: StrPath, model_json: StrPath | None = None) -> CollapseCase:
    """Write one case's deck (engine-neutral JSON) from its case-table row; returns the case.
    model_json: a calibrated model's GNS dataset's row is a case of that model (pipeline.cases; a
    campaign's dataset that the config alone makes holds its model in the row, model_by_config);
    its deck's row then holds the model's parameters there ("parameters": {name: value}), which
    the trajectory records."""
    if row.get("calibrated"):
        # imported here: the decks of every other case load no calibration code
        from pipeline.calibrated_gns import model_case

        case, parameters = model_case(model_json, row)
        case = grid.write_deck(dict(row, parameters=parameters), path, case)
    else:
        case = grid.write_deck(row, path)
    log.info(
        "deck %s: %d grains, dt %.3g s, %d frames every %.3g s",
        case.name,
        case.n_particles,
        case.time_step,
        case.n_frames,
        case.frame_interval,
    )
    return case


def job_resources(row: dict, stage: str, threads: int = 1, attempt: int = 1) -> dict:
    """{"runtime": minutes, "mem_mb": MB} that the DEM job `stage` ("settle" or "collapse") of a
    case-table row asks for: it scales with grains x steps, so a full-scale case asks for hours
    where a coarse one asks for minutes. A second thread counts as 0.7 of one (measured 1.7x). A
    calibrated model's case asks for its template's: the model changes the contacts, not the
    grains or the frames."""
    case = grid.case_from_row(row.get("template", row))
    if stage == "settle":
        steps = SETTLE_TSTAR_REQUESTED * case.t_star / settle_time_step(case)
    elif stage == "collapse":
        steps = (case.n_frames - 1) * frame_steps(case.frame_interval, case.time_step)[0]
    else:
        raise ValueError(f"job_resources: unknown stage {stage!r} (settle or collapse)")
    seconds = case.n_particles * steps / (REQUEST_PARTICLE_STEPS_PER_S * (1 + 0.7 * (threads - 1)))
    frames_mb = 4 * case.n_frames * case.n_particles * 2 * 4 / 1e6  # float32 (x, y) per grain and frame
    return {
        "runtime": max(MIN_RUNTIME_MIN, math.ceil(seconds / 60)) * 2 ** (attempt - 1),
        "mem_mb": BASE_MEMORY_MB + math.ceil(frames_mb),
    }


def settle(deck_path: StrPath, out_path: StrPath, threads: int = 1) -> Trajectory:
    """Pour and settle one case's column behind the gate (builtin engine, `threads` as config
    dem.threads); writes the settled packing as a one-frame trajectory HDF5 at `out_path` (its
    attribute wall_time_s: the settle's wall seconds) and returns it."""
    case, _ = grid.read_deck(deck_path)
    threads = usable_threads(threads)
    log.info("settling %s: %d grains, %d thread(s)", case.name, case.n_particles, threads)
    # progress: how close the RMS grain speed is to the rest criterion (it can fall back, and is
    # logged each time it passes another tenth)
    start = time.perf_counter()
    packing = settle_column(case, progress_logger(f"settling {case.name}, rest criterion", log), threads)
    packing.attrs["wall_time_s"] = time.perf_counter() - start  # the settle's cost (a run's: its collapse's)
    write_trajectory(out_path, packing)
    log.info(
        "settled height %.4g m after %s steps in %.1f s",
        packing.attrs["settled_height"],
        packing.attrs["settle_steps"],
        packing.attrs["wall_time_s"],
    )
    return packing


def clear_work_dir(work_dir: StrPath, keep: tuple[str, ...] = ()) -> None:
    """Remove what a killed run left in work_dir, but for the files named in `keep`."""
    work_dir = Path(work_dir)
    if not work_dir.is_dir():
        shutil.rmtree(work_dir, ignore_errors=True)
        return
    for path in work_dir.iterdir():
        if path.name in keep and path.is_file():
            log.info("keeping %s: the run resumes from it", path)
            continue
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()


def run_case(
    deck_path: StrPath,
    packing_path: StrPath,
    out_path: StrPath,
    engine: str,
    solvers: dict,
    keep_work: bool,
    work_dir: StrPath,
    threads: int = 1,
) -> Trajectory:
    """Run one case's collapse from its settled packing with `engine` (a dem.engines name;
    `solvers`: config dem.solvers; `threads`: config dem.threads); writes the trajectory HDF5 at
    `out_path` and returns it.

    work_dir: the engine's scratch folder, emptied first (a killed run's leftovers, but for the
    files the engine resumes from: a killed builtin run goes on from its checkpoint) and removed
    afterwards unless `keep_work`.
    """
    case, row = grid.read_deck(deck_path)
    packing = read_trajectory(packing_path)
    dem_engine = get_engine(engine, {"solvers": dict(solvers), "threads": threads})
    log.info(
        "collapse %s with the %s engine (%s): %d grains, %d frames",
        case.name,
        dem_engine.name,
        dem_engine.version(),
        case.n_particles,
        case.n_frames,
    )

    clear_work_dir(work_dir, keep=dem_engine.resume_files)
    trajectory = dem_engine.simulate(case, packing, work_dir, progress=progress_logger(f"collapse {case.name}", log))
    trajectory.attrs.update(row.get("parameters", {}))  # a calibrated model's: the GNS's inputs
    write_trajectory(out_path, trajectory)  # atomic, once the engine's output reads whole
    if not keep_work:
        shutil.rmtree(work_dir)
    log.info(
        "done: %d frames of %d grains (engine %s)",
        trajectory.n_frames,
        trajectory.n_particles,
        trajectory.attrs["engine"],
    )
    return trajectory


def draw_case(trajectory_path: StrPath, out_path: StrPath, runout: RunoutMethod | dict | str) -> None:
    """Snapshots and runout curve of one case's collapse (L* read by `runout`, the configured
    method) at `out_path`."""
    from dem.plots import plot_case  # matplotlib: only the figure jobs pay for its import

    trajectory = read_trajectory(trajectory_path)
    plot_case(trajectory, out_path, runout)
