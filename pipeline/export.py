"""The ParaView export stage (workflow/rules/export.smk; config `export_vtk`, off by default).

  - `export_trajectory_vtk` (rule export_vtk): one trajectory HDF5 under results/ (a GNS test-split
    rollout, the DEM run of the same case, a DEM validation run) -> results/vtk/<its path>/;
  - `export_calibrated_vtk` (rule export_calibrated_vtk): the calibrated model's answer on its
    validation packings -> results/vtk/calibrated/<name>/packing_<seed>/. The validation keeps only
    the runout curves of those runs, so they are run again here (same case, packing, engine) and
    each rerun's runout is checked against the curve the validation recorded.

The method is dem/vtk.py's (files, units, how the velocity is computed).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from calibration.calibrated import CalibrationError, read_model
from calibration.calibrated_result import CalibratedResult
from calibration.design_runs import SimulationSettings
from calibration.measured import load_column
from calibration.objective import simulated_runout_at
from dem.atomic import StrPath, atomic_dir
from dem.engines import FAILURES, simulate_case
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from dem.vtk import ExportError, VtkExport, export_file, export_trajectory

log = logging.getLogger(__name__)
RERUN_TOLERANCE = 1e-6  # L*: a rerun of a validation packing reproduces its recorded curve within this


def export_trajectory_vtk(trajectory_path: StrPath, outdir: StrPath) -> VtkExport:
    """The trajectory HDF5 at `trajectory_path` as a ParaView time series in `outdir` (dem.vtk)."""
    export = export_file(trajectory_path, outdir, progress=progress_logger(f"export {trajectory_path}", log))
    log.info("%s: %d frames -> %s", trajectory_path, len(export.frames), export.pvd)
    return export


def export_calibrated_vtk(
    calibrated_path: StrPath,
    model_path: StrPath,
    measured_path: StrPath,
    outdir: StrPath,
    *,
    channel_width: float,
    dem: dict | None,
) -> list[VtkExport]:
    """The DEM validation runs of the calibrated model's answer (calibrated.json, rule calibrated) as
    ParaView time series, <outdir>/packing_<seed>/, one per validation packing that ran; the runs are
    repeated with the validation's case, packing seed and engine (dem: the config's dem section).
    A rerun whose runout departs from the recorded curve by more than RERUN_TOLERANCE is exported
    with a warning (the code or the engine changed since the validation). Written atomically."""
    result = CalibratedResult.from_json(calibrated_path)
    route = next((r for r in result.routes if r["route"] == result.answer and r["model"] == result.model), None)
    if route is None:
        raise CalibrationError(f"{calibrated_path}: no validated route {result.answer!r} of the {result.model} model")
    model, _ = read_model(model_path, channel_width)
    column = load_column(measured_path)
    settings = SimulationSettings(size_scale=result.size_scale)
    runout = RunoutMethod.from_config(result.runout)
    theta = [route["parameters"][name] for name in model.parameter_names]
    outdir = Path(outdir)
    exports = []
    with atomic_dir(outdir) as tmp:
        for seed, recorded in zip(route["seeds"], route["curves"]):
            if recorded is None:
                log.warning("%s: packing %d failed in the validation; not exported", result.answer, seed)
                continue
            try:
                trajectory = simulate_case(model.case(column, theta, settings, seed), dem)
            except FAILURES as exc:
                log.warning("%s: packing %d failed on rerun (%s); not exported", result.answer, seed, exc)
                continue
            t, curve = runout.curve(trajectory)
            gap = float(np.max(np.abs(simulated_runout_at(t, curve, column) - np.asarray(recorded))))
            if gap > RERUN_TOLERANCE:
                log.warning("packing %d: the rerun's L* departs from the validation's by up to %.3g", seed, gap)
            exports.append(export_trajectory(trajectory, tmp / f"packing_{seed}", f"packing_{seed}"))
            log.info(
                "%s at %s, packing %d: %d frames, L* within %.2g of the validation's",
                result.answer,
                theta,
                seed,
                len(exports[-1].frames),
                gap,
            )
        if outdir.is_dir() and not any(outdir.iterdir()):
            outdir.rmdir()
        if outdir.exists():  # Snakemake removes a directory output before its job runs
            raise ExportError(f"{outdir}: exists and is not empty; remove it first")

    def moved(path: Path) -> Path:
        return outdir / path.relative_to(tmp)

    return [VtkExport(moved(e.pvd), [moved(f) for f in e.frames], e.times) for e in exports]
