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
import shutil

from dem import grid
from dem.atomic import StrPath
from dem.case import CollapseCase
from dem.engines import get_engine
from dem.packing import settle_column
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from dem.trajectory import Trajectory, read_trajectory, write_trajectory

log = logging.getLogger(__name__)


def write_deck(row: dict, path: StrPath) -> CollapseCase:
    """Write one case's deck (engine-neutral JSON) from its case-table row; returns the case."""
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


def settle(deck_path: StrPath, out_path: StrPath) -> Trajectory:
    """Pour and settle one case's column behind the gate (builtin engine); writes the settled
    packing as a one-frame trajectory HDF5 at `out_path` and returns it."""
    case, _ = grid.read_deck(deck_path)
    log.info("settling %s: %d grains", case.name, case.n_particles)
    packing = settle_column(case, progress=lambda done: log.info("settling: rest criterion %.0f%%", 100 * done))
    write_trajectory(out_path, packing)
    log.info("settled height %.4g m after %s steps", packing.attrs["settled_height"], packing.attrs["settle_steps"])
    return packing


def run_case(
    deck_path: StrPath,
    packing_path: StrPath,
    out_path: StrPath,
    engine: str,
    solvers: dict,
    keep_work: bool,
    work_dir: StrPath,
) -> Trajectory:
    """Run one case's collapse from its settled packing with `engine` (a dem.engines name;
    `solvers`: config dem.solvers); writes the trajectory HDF5 at `out_path` and returns it.

    work_dir: the engine's scratch folder, emptied first (a killed run's leftovers) and removed
    afterwards unless `keep_work`.
    """
    case, _ = grid.read_deck(deck_path)
    packing = read_trajectory(packing_path)
    dem_engine = get_engine(engine, {"solvers": dict(solvers)})
    log.info(
        "collapse %s with the %s engine (%s): %d grains, %d frames",
        case.name,
        dem_engine.name,
        dem_engine.version(),
        case.n_particles,
        case.n_frames,
    )

    shutil.rmtree(work_dir, ignore_errors=True)  # a killed run's leftovers
    # writes the output atomically, only once the engine's output reads whole
    trajectory = dem_engine.simulate(
        case, packing, work_dir, progress=progress_logger(f"collapse {case.name}", log), output=out_path
    )
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
