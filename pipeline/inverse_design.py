"""The inverse-design stage's jobs that run a GNS (workflow/rules/inverse.smk; the DEM runs, the
comparison and the section: pipeline/inverse.py): per measured column the GNS inverse design
(run_inverse_design, also the calibrated model's, pipeline/calibrated_inverse.py); per dataset the
parameter recovery of synthetic DEM targets (run_recovery). The methods live in calibration.inverse
(with calibration.gns_objective, calibration.lbfgsb and calibration.inverse_plots) and
calibration.recovery.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from calibration.gns_objective import GNSObjective
from calibration.inverse import inverse_design
from calibration.inverse_plots import plot_deposits, plot_paths
from calibration.inverse_result import InverseResult, write_result
from calibration.measured import load_column
from calibration.measured_column import MeasuredColumn
from calibration.recovery import plot_recovery, recovery_study
from dem.atomic import StrPath, write_json
from dem.run_store import keeps_runs
from dem.runout import RunoutMethod, check_same_method
from dem.trajectory import read_trajectory
from gns.dataset import read_metadata, read_training_attrs
from gns.evaluate import runout_error_at
from gns.simulator import load_simulator
from pipeline.inverse import START_NAMES

log = logging.getLogger(__name__)


def model_error_from_evaluation(
    path: StrPath | None, runout: RunoutMethod, t_over_tstar: Sequence[float] | np.ndarray
) -> np.ndarray | None:
    """RMS runout error (L*) [K] of the GNS against the DEM on its test split at t/t* points [K]
    (gns.evaluate's summary, which must have been read by the same runout method); None without one,
    or where every test rollout failed (no error measured: the posterior's noise goes without it)."""
    if not path:
        return None
    summary = json.loads(Path(path).read_text())
    check_same_method(summary.get("runout"), runout, f"GNS evaluation {path}")
    try:
        return runout_error_at(summary, t_over_tstar)
    except ValueError as exc:
        raise ValueError(f"GNS evaluation {path}: {exc}") from None


def run_inverse_design(
    model_path: StrPath,
    metadata_path: StrPath,
    start_path: StrPath | Sequence[StrPath],
    measured_path: StrPath,
    out_json: StrPath,
    out_paths: StrPath,
    out_deposits: StrPath,
    settings: dict,
    *,
    runout: dict | None,
    evaluation_path: StrPath | None = None,
    doe_responses_path: StrPath | None = None,
    threads: int | None = None,
    design_names: Sequence[str] = START_NAMES,
    start_values: dict | None = None,
    optimiser: dict | None = None,
    dataset_paths: Sequence[StrPath] = (),
) -> InverseResult:
    """The inverse-design stage of one measured column: inverse.json and the two figures.
    start_path: the start run, or several packings of the column (GNSObjective's starts).

    settings: the config's `inverse` section (friction, restitution bounds, start, starts, gradient,
    fd_step, max_iterations, landscape_levels, seed); runout: the config's `runout` section (every L*
    is read by it). evaluation_path: the GNS's test-split summary
    (its runout error joins the noise model); doe_responses_path: the DoE's DEM objective values,
    drawn under the paths. threads: torch's CPU threads (the job's; None: torch's default).
    design_names: the parameters designed (the GNS's inputs; bounds from settings[name], else the
    range the GNS was trained on); start_values: {name: value} of the start run that its file does
    not record (the start run of the base model has a mechanism at its off value), also the first
    start of a parameter beyond inverse.start. optimiser: {"optimiser": "lbfgsb" | "bayesopt",
    "budget", "n_initial"} (calibration.inverse.inverse_design's; None: the paper's L-BFGS-B).
    dataset_paths: the DEM runs of the GNS's dataset, against which the GNS's response to each
    design parameter is checked (calibration.sensitivity; none: no check).
    A GNS of an extended model's dataset that holds the base model's runs too (metadata's
    parameter_off) runs the base model where the mechanism's parameter is not designed: it is held
    at its off value, or tied to the parameter that value follows (floor friction = grain friction).
    """
    if threads:
        torch.set_num_threads(threads)
    metadata = read_metadata(metadata_path)
    simulator = load_simulator(model_path, metadata)
    measured = load_column(measured_path)
    paths = [start_path] if isinstance(start_path, (str, os.PathLike)) else list(start_path)
    starts = [read_trajectory(path) for path in paths]
    off = {k: v for k, v in (metadata.get("parameter_off") or {}).items() if k not in design_names}
    held = {k: float(v) for k, v in off.items() if not isinstance(v, str)}
    tied = {k: v for k, v in off.items() if isinstance(v, str)}
    for packing in starts:  # a start run of the base model records no mechanism parameter
        packing.attrs = {**(start_values or {}), **packing.attrs, **held}
    name = metadata["name"]
    log.info("design %s through the GNS of dataset %s; held off %s, tied %s", design_names, name, held, tied)
    # the GNS's test-split error was read by the config's method; the design reads the column's way
    model_error = model_error_from_evaluation(evaluation_path, RunoutMethod.from_config(runout), measured.t_over_tstar)
    runout = measured.runout_reading(runout)
    first_start = dict(zip(START_NAMES, settings["start"]))
    result = inverse_design(
        simulator,
        starts,
        measured,
        metadata,
        read_training_attrs(metadata),
        bounds=[settings.get(name) for name in design_names],
        n_starts=settings["starts"],
        first_start=[first_start.get(name, (start_values or {}).get(name)) for name in design_names],
        gradient=settings["gradient"],
        fd_step=settings["fd_step"],
        max_iterations=settings["max_iterations"],
        model_error_std=model_error,
        landscape_levels=settings["landscape_levels"] if len(design_names) == 2 else 0,
        seed=settings["seed"],
        design_names=design_names,
        runout=runout,
        reference=dataset_runs(dataset_paths, design_names, measured, runout) if dataset_paths else None,
        tied=tied,
        **(optimiser or {}),
    )
    write_result(result, out_json)
    dem_points = None
    if doe_responses_path:
        from doe.study import read_responses  # the DoE's DEM points drawn under the paths

        table = read_responses(doe_responses_path, runout)
        dem_points = {name: table[name].to_numpy(float) for name in list(result.names) + ["mse"]}
    plot_paths(result.to_dict(), out_paths, dem_points)
    best = min(result.starts, key=lambda r: r.value)
    middle = best.iterates[len(best.iterates) // 2][0]
    plot_deposits(
        GNSObjective(simulator, starts[0], measured, result.names, runout=runout, tied=tied),
        {"start": best.start, f"iteration {len(best.iterates) // 2}": middle, "optimum": best.params},
        out_deposits,
    )
    return result


def dataset_runs(
    paths: Sequence[StrPath], names: Sequence[str], measured: MeasuredColumn, runout: RunoutMethod
) -> tuple[np.ndarray, np.ndarray]:
    """(parameters [n, P] in the order of names, L* [n, K] at the measured t/t*) of the DEM runs at
    paths (a GNS's dataset), each read by `runout`."""
    runs = [read_trajectory(path) for path in paths]
    points = np.array([[float(run.attrs[name]) for name in names] for run in runs])
    return points, np.array([runout.at(run, measured.t_over_tstar) for run in runs])


@keeps_runs("out_json")
def run_recovery(
    model_path: StrPath,
    metadata_path: StrPath,
    out_json: StrPath,
    out_figure: StrPath,
    *,
    runout: dict | None,
    evaluation_path: StrPath | None = None,
    dem: dict | None = None,
    threads: int | None = None,
    **study_kwargs: Any,
) -> dict:
    """The recovery stage: recovery_study with the GNS at model_path, L* read by `runout` (the
    config's runout section), DEM runs by the engine of `dem` (the config's dem section); writes
    JSON and figure. threads: torch's CPU threads (the job's; None: torch's default)."""
    if threads:
        torch.set_num_threads(threads)
    metadata = read_metadata(metadata_path)
    runout = RunoutMethod.from_config(runout)
    summary = recovery_study(
        load_simulator(model_path, metadata),
        metadata,
        model_error=(lambda t: model_error_from_evaluation(evaluation_path, runout, t)) if evaluation_path else None,
        runout=runout,
        dem_config=dem,
        **study_kwargs,
    )
    write_json(out_json, summary)
    plot_recovery(
        summary,
        out_figure,
        title=f"{metadata['name']} (targets: mean of {summary['packings']} packings): mu "
        f"within {summary['mu_tolerance']:g} in {summary['mu_within']} of {summary['n_cases']}, truth inside "
        f"95% in {summary['truth_inside_95']}",
    )
    return summary
