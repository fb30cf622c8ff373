"""Synthetic "measured" data with a hidden mechanism, for testing the diagnosis against a known answer.

A hidden truth is the base model (mu, e) plus at most one candidate mechanism at a magnitude drawn
from its stated `hidden_range` (calibration/mechanisms.py), simulated by the builtin DEM on a packing
seed that the diagnosis' own runs never use, observed like a measurement (runout L* at t/t* points,
deposit height at x points) and perturbed by Gaussian measurement noise of a stated std. The
diagnosis is then given the data and the noise level, never the truth.

Two ways to simulate the truth: `synthetic_measurement`, the builtin DEM with the very model the
diagnosis fits, and `liggghts_measurement`, another solver (LIGGGHTS, a Hertzian contact law, its
own packing, its own runout reading), as real data never come from the model that fits them. Each
writes the runout reading it used into its columns (`runout_method`, as a measured file states it),
so the diagnosis reads its own runs the same way.
"""

from __future__ import annotations

import csv
import os
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from calibration.design_runs import Library, SimulationSettings
from calibration.measured import OPTIONAL_FIELDS, REQUIRED_FIELDS
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import Mechanism
from calibration.model import Model
from calibration.observables import Observables
from dem.atomic import atomic_path
from dem.case import MATERIALS, CollapseCase
from dem.engines import BUILTIN, simulate_case
from dem.engines.liggghts_hertz import LiggghtsHertzEngine, poured_column
from dem.runout import RunoutMethod

if TYPE_CHECKING:  # diagnosis does not depend on this module; this module calls it only in diagnose_hidden_cases
    from calibration.diagnosis import DiagnosisSettings
    from calibration.diagnosis_result import Diagnosis
    from dem.trajectory import Trajectory

# The test columns of the diagnosis: small quartz columns of two aspect ratios, runout every 0.5 t*
# up to 5 t* (the paper stops at 3.5; by 5 the base model's front still creeps on while rolling
# resistance has stopped it, which is what tells rolling resistance from side-wall drag), and the
# deposit profile read as another lab or solver would read it, not as the model would by default:
# densely (a point every 3 real grain diameters, from 0.1 to 3 L_i: ~46 points a column against 10
# runout points), in bins of 2 real grain diameters, half a t* after the runout record ends.
SYNTHETIC_TIMES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0)
SYNTHETIC_PROFILE_SPAN_OVER_L_I = (0.1, 3.0)
SYNTHETIC_PROFILE_STEP_DIAMETERS = 3.0  # spacing of the profile's x points, in real grain diameters
SYNTHETIC_PROFILE_BIN_DIAMETERS = 2.0  # its bin width, in real grain diameters
SYNTHETIC_PROFILE_READ_AT = 5.5  # t/t*
# Inner part of the base box the hidden (mu, e) are drawn from: away from the edges, so that a
# base-model truth is inside what the calibration can reach.
TRUTH_BOX = ((0.4, 0.8), (0.4, 0.8))
SEED_OFFSET = 10_000  # hidden packing seeds start here, far from the library's packing seeds
# How liggghts_measurement reads its runout, as off a lab's images: the front of the mass connected
# to the column's foot (a grain's gap to it under 2 d) that never moves back, not the diagnosis'
# default dense front (which needs 8 neighbours within 2.4 d, so leaves out a thin tongue).
LAB_RUNOUT = RunoutMethod("connected_front_reached")


@dataclass(frozen=True)
class HiddenTruth:
    """What generated the data: base parameters, the hidden mechanism (None: base model) and its
    magnitude in the mechanism's own parameter, and the packing seed."""

    friction: float
    restitution: float
    mechanism: str | None
    magnitude: float | None
    seed: int

    def to_dict(self) -> dict:
        return asdict(self)


def draw_truth(rng: np.random.Generator, mechanism: Mechanism | None) -> HiddenTruth:
    """A random truth with `mechanism` (None: the null case) at a magnitude in its hidden_range."""
    friction, restitution = (float(rng.uniform(*box)) for box in TRUTH_BOX)
    magnitude = None if mechanism is None else float(rng.uniform(*mechanism.hidden_range))
    return HiddenTruth(
        friction,
        restitution,
        None if mechanism is None else mechanism.name,
        magnitude,
        SEED_OFFSET + int(rng.integers(0, 10_000)),
    )


def synthetic_columns(
    material: str = "quartz",
    L_i: float = 0.02,
    aspect_ratios: Sequence[float] = (1.0, 2.0),
    times: Sequence[float] = SYNTHETIC_TIMES,
    profile_step_diameters: float | None = SYNTHETIC_PROFILE_STEP_DIAMETERS,
    profile_read_at: float = SYNTHETIC_PROFILE_READ_AT,
    profile_bin_diameters: float = SYNTHETIC_PROFILE_BIN_DIAMETERS,
    runout_method: str | None = None,
) -> list[MeasuredColumn]:
    """Columns to be "measured" (values still zero): one per aspect ratio, runout L* at `times`
    (t/t*), deposit height every `profile_step_diameters` real grain diameters over
    SYNTHETIC_PROFILE_SPAN_OVER_L_I x L_i (None: no profile), read at t/t* = `profile_read_at` in
    bins of `profile_bin_diameters` real grain diameters; L_i in m. runout_method: how their runout
    will be read (a dem.runout method; None: not stated, the measurement's own)."""
    times = np.asarray(times, float)
    diameter = MATERIALS[material].diameter
    profile_x = np.array([])
    if profile_step_diameters is not None:
        low, high = (f * L_i for f in SYNTHETIC_PROFILE_SPAN_OVER_L_I)
        # to the micrometre, so a CSV round trip gives the same points back
        profile_x = np.round(np.arange(low, high + 1e-12, profile_step_diameters * diameter), 6)
    return [
        MeasuredColumn(
            name=f"{material}_a{a:g}",
            material=material,
            aspect_ratio=float(a),
            L_i=L_i,
            t_over_tstar=times,
            runout=np.zeros_like(times),
            runout_std=None,
            profile_x=profile_x if len(profile_x) else None,
            profile_height=np.zeros_like(profile_x) if len(profile_x) else None,
            source="synthetic",
            profile_read_at=profile_read_at if len(profile_x) else None,
            profile_bin_width=profile_bin_diameters * diameter if len(profile_x) else None,
            runout_method=runout_method,
        )
        for a in aspect_ratios
    ]


def synthetic_measurement(
    truth: HiddenTruth,
    columns: Sequence[MeasuredColumn],
    mechanisms: Sequence[Mechanism],
    settings: SimulationSettings,
    runout_noise: float,
    profile_noise: float,
    rng: np.random.Generator,
    runout: dict | RunoutMethod | str | None = None,
) -> tuple[list[MeasuredColumn], np.ndarray]:
    """The columns "measured" under `truth` by the builtin DEM (the model the diagnosis fits):
    DEM observables plus Gaussian noise; runout: how its L* is read where a column states no method
    (dem.runout.RunoutMethod; None: the default), stated in the columns returned.

    runout_noise: std of L* (-), stored as each runout row's std; profile_noise: std of the deposit
    height (m). mechanisms: the candidates, to find the truth's by name. Returns (columns, clean
    observables [q] before noise).
    """
    observables = Observables(columns, runout)
    # the truth settles its own packing with its own contact law, as a real column would
    cases = truth_cases(truth, observables.columns, mechanisms, settings)
    trajectories = [simulate_case(case, BUILTIN) for case in cases]
    return noisy_columns(observables, trajectories, runout_noise, profile_noise, rng)


def liggghts_measurement(
    truth: HiddenTruth,
    columns: Sequence[MeasuredColumn],
    mechanisms: Sequence[Mechanism],
    settings: SimulationSettings,
    runout_noise: float,
    profile_noise: float,
    rng: np.random.Generator,
    runout: dict | RunoutMethod | str | None = LAB_RUNOUT,
) -> tuple[list[MeasuredColumn], np.ndarray]:
    """As synthetic_measurement, but the truth is simulated by another solver: LIGGGHTS with a
    Hertz (+ SJKR cohesion, + EPSD2 rolling friction) contact law and a floor of its own, settling
    its own packing (dem/engines/liggghts_hertz.py), and the runout read the lab's way
    (LAB_RUNOUT, where a column states no method), stated in the columns returned, so that the
    diagnosis reads its own runs the same way. The grains are the coarse-grained ones the diagnosis
    simulates (settings.size_scale), drawn with the truth's seed."""
    observables = Observables(columns, runout)
    engine = LiggghtsHertzEngine()
    trajectories = []
    for case in truth_cases(truth, observables.columns, mechanisms, settings):
        with tempfile.TemporaryDirectory(prefix="liggghts_truth_") as work_dir:
            trajectories.append(engine.simulate(case, poured_column(case), work_dir))
    return noisy_columns(observables, trajectories, runout_noise, profile_noise, rng)


def truth_cases(
    truth: HiddenTruth, columns: Sequence[MeasuredColumn], mechanisms: Sequence[Mechanism], settings: SimulationSettings
) -> list[CollapseCase]:
    """The CollapseCase of each column under `truth` (mechanism found by name in `mechanisms`),
    coarse-grained per settings, on the truth's packing seed."""
    known = {m.name: m for m in mechanisms}
    model = Model(None if truth.mechanism is None else known[truth.mechanism])
    theta = [truth.friction, truth.restitution] + ([] if truth.mechanism is None else [truth.magnitude])
    return [model.case(c, theta, settings, truth.seed) for c in columns]


def noisy_columns(
    observables: Observables,
    trajectories: Sequence[Trajectory],
    runout_noise: float,
    profile_noise: float,
    rng: np.random.Generator,
) -> tuple[list[MeasuredColumn], np.ndarray]:
    """The observables' columns holding the observables of one trajectory per column plus Gaussian
    noise (runout std runout_noise (-), profile std profile_noise (m), both stated in the columns),
    each stating its simulated grain diameter and how its runout was read; and the clean
    observables [q]."""
    clean = observables.from_trajectories(trajectories)
    noisy = clean + rng.normal(0.0, 1.0, clean.shape) * np.where(
        observables.kind == "runout", runout_noise, profile_noise
    )
    out, k = [], 0
    for c, trajectory in zip(observables.columns, trajectories, strict=True):
        n_t = len(c.t_over_tstar)
        runout, k = noisy[k : k + n_t], k + n_t
        profile = None
        if c.profile_x is not None:
            profile, k = np.maximum(noisy[k : k + len(c.profile_x)], 0.0), k + len(c.profile_x)
        out.append(
            replace(
                c,
                runout=runout,
                runout_std=np.full(n_t, runout_noise),
                profile_height=profile,
                profile_std=None if profile is None else np.full(len(profile), profile_noise),
                # the truth's grains are the simulation's: say so, as a solver's data file would
                grain_diameter=float(trajectory.attrs["diameter"]),
                runout_method=observables.reading(c).method,
            )
        )
    return out, clean


def write_measured_csv(columns: Sequence[MeasuredColumn], path: str | os.PathLike, comment: str = "") -> None:
    """Write columns in the measured-data CSV schema (calibration/measured.py)."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as handle:
            for line in comment.splitlines():
                handle.write(f"# {line}\n")
            writer = csv.writer(handle)
            writer.writerow(REQUIRED_FIELDS + OPTIONAL_FIELDS)
            for c in columns:
                grain = "" if c.grain_diameter is None else f"{c.grain_diameter:.10g}"
                # a material of the CSV's own: its density and solid fraction (empty for a table's)
                own = ["" if v is None else f"{v:.10g}" for v in (c.density, c.solid_fraction)]
                std = c.runout_std if c.runout_std is not None else [None] * len(c.runout)
                method = c.runout_method or ""
                for t, value, s in zip(c.t_over_tstar, c.runout, std):
                    writer.writerow(
                        [
                            c.name,
                            c.material,
                            c.aspect_ratio,
                            c.L_i,
                            "runout",
                            f"{t:g}",
                            f"{value:.6g}",
                            "" if s is None else f"{s:.6g}",
                            "",
                            "",
                            grain,
                            *own,
                            method,
                        ]
                    )
                if c.profile_x is not None:
                    std = c.profile_std if c.profile_std is not None else [None] * len(c.profile_x)
                    read_at = "" if c.profile_read_at is None else f"{c.profile_read_at:g}"
                    bin_width = "" if c.profile_bin_width is None else f"{c.profile_bin_width:.6g}"
                    for x, height, s in zip(c.profile_x, c.profile_height, std):
                        writer.writerow(
                            [
                                c.name,
                                c.material,
                                c.aspect_ratio,
                                c.L_i,
                                "profile",
                                f"{x:.10g}",
                                f"{height:.6g}",
                                "" if s is None else f"{s:.6g}",
                                read_at,
                                bin_width,
                                grain,
                                *own,
                                "",
                            ]
                        )


def evidence_margins(result: Diagnosis) -> dict:
    """How far a diagnosis' evidence lies from its decision rule, each BIC gain against one reference.

    delta_bic_dem: BIC(base) - BIC(candidate), both from DEM runs, for the models scored in the DEM;
    delta_bic_emulator: the same from the final emulator fits, for every candidate (the two must not
    be mixed: the emulator's base fit can be worse than the DEM's). margins: the DEM-best
    candidate's BIC lead over the base model and over the DEM runner-up, and its held-out chi^2
    gain over the base model (the rule asks for min_delta_bic_vs_base, min_delta_bic_vs_runner_up
    and min_heldout_gain).
    """
    base_dem = result.base.dem
    scored = {n: c.dem for n, c in result.candidates.items() if c.dem is not None}
    base_final = result.base.emulator_final.bic
    ranked = sorted(scored, key=lambda n: scored[n].bic)
    best = scored[ranked[0]]
    return {
        "delta_bic_dem": {n: round(base_dem.bic - d.bic, 2) for n, d in scored.items()},
        "delta_bic_emulator": {n: round(base_final - c.emulator_final.bic, 2) for n, c in result.candidates.items()},
        "margins": {
            "dem_best": ranked[0],
            "bic_vs_base": round(base_dem.bic - best.bic, 2),
            "bic_vs_runner_up": (round(scored[ranked[1]].bic - best.bic, 2) if len(ranked) > 1 else None),
            "heldout_gain": round(1 - best.heldout_chi2 / base_dem.heldout_chi2, 3),
        },
    }


def diagnose_hidden_cases(
    truths: Sequence[HiddenTruth],
    settings: DiagnosisSettings,
    columns: list[MeasuredColumn] | None = None,
    runout_noise: float = 0.05,
    profile_noise: float = 0.5e-3,
    seed: int = 0,
    library: Library | None = None,
    progress: Callable[[float], None] | None = None,
    measurement: Callable | None = None,
) -> dict:
    """Generate data for each HiddenTruth, diagnose it without the truth, and score the verdicts.

    settings: a calibration.diagnosis.DiagnosisSettings (its profile_noise is set to the stated
    `profile_noise`; the runout noise travels in the data as each point's std). columns: the
    columns to measure (default `synthetic_columns()`); library: their design runs, read as the
    data state their runout was read (built here when None, for the first data made).
    measurement: how data are made of a truth, called as synthetic_measurement is (without
    `runout`); None: synthetic_measurement reading the runout as the diagnosis does.
    Returns {"cases": [...], "hit_rate", "null_correct", "library_seconds"}; each case holds its
    Diagnosis as "result".
    """
    from calibration.design_runs import DEMRunner
    from calibration.diagnosis import diagnose  # here: diagnosis does not depend on this module

    columns = synthetic_columns() if columns is None else columns
    settings = replace(settings, profile_noise=profile_noise)
    mechanisms = [m.mechanism for m in settings.models()[1:]]
    runner = None
    if measurement is None:
        measurement = partial(synthetic_measurement, runout=settings.runout)
    rng = np.random.default_rng(seed)
    cases = []
    for k, truth in enumerate(truths):
        data, _ = measurement(truth, columns, mechanisms, settings.simulation, runout_noise, profile_noise, rng)
        if runner is None:  # the runs are read as the data state their runout was read
            observables = Observables(data, settings.runout)
            library = settings.library(observables) if library is None else library
            runner = DEMRunner(observables, settings.simulation)
        result = diagnose(data, settings, library=library, runner=runner, name=f"hidden_{k}")
        expected = truth.mechanism or "none"
        fitted = None
        if truth.mechanism is not None:
            fitted = result.candidates[truth.mechanism].score.parameters
        errors = result.errors
        cases.append(
            {
                "truth": truth.to_dict(),
                "cause": result.cause,
                "hit": result.cause == expected,
                "checks": result.checks,
                "compared_model": errors.compared_model,
                "fit_mse": errors.fit_mse.to_dict(),
                "heldout_mse": errors.heldout_mse.to_dict(),
                "fit_chi2": errors.fit_chi2.to_dict(),
                "heldout_chi2": errors.heldout_chi2.to_dict(),
                **evidence_margins(result),
                "fitted_parameters_of_true_mechanism": fitted,
                "seconds": result.seconds,
                "result": result,
            }
        )
        if progress is not None:
            progress((k + 1) / len(truths))
    hidden = [c for c in cases if c["truth"]["mechanism"] is not None]
    nulls = [c for c in cases if c["truth"]["mechanism"] is None]
    return {
        "cases": cases,
        "hits": sum(c["hit"] for c in hidden),
        "n_hidden": len(hidden),
        "hit_rate": sum(c["hit"] for c in hidden) / len(hidden) if hidden else None,
        "null_correct": all(c["hit"] for c in nulls) if nulls else None,
        "library_seconds": float(sum(r.seconds.sum() for r in library.runs.values())) if library is not None else 0.0,
    }
