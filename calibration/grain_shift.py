"""How far a model's runout curve moves when the grains get finer, at the same parameters: the
part of its answer that will not transfer to another resolution.

A coarse-grained calibration gives parameters of its grain size; the engineer simulates at
another (calibration.target_size_scale). The target correction (calibration/target_scale.py)
absorbs the move between the calibration's scale and the target, but a model whose curve moves a
lot with the grain size keeps moving beyond the target: on the default DAG the answer's curve moved
by MSE 0.16-0.30 from size_scale 3 to 2 (docs/experiments/target-scale.md), more than its fit. So
`calibration.model: auto` weighs each contender's move too (calibration.contenders): its fit run on
the measured column at the calibration's grain size and at the finer one, on the same packing
seeds, the move of the mean L* curve in units of the data's noise.

The move is estimated from means of R packings each, whose own scatter adds to it: (m_f - m_c)^2
has expectation move^2 + s_f^2 / R + s_c^2 / R. Each point's square is taken less that scatter (the
packings' sample variances), and not below 0, so a model that does not move scores about 0 however
few packings ran.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from calibration.calibrated import VALIDATION_SEED0, validate
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from dem.runout import RunoutMethod


@dataclass
class GrainShift:
    """A model's mean L* curve [K] at the measured t/t* at two grain sizes, same parameters and seeds.

    size_scales: (the calibration's, the finer); seeds [R]; coarse_mean, fine_mean [K] (None where no
    run ran); shift_mse: the debiased mean over t of the squared move (L*^2); chi2: the sum over t
    of the debiased squared move over noise [K]^2 (dimensionless; None: no time where both ran);
    seconds: the DEM's wall time."""

    size_scales: tuple[float, float]
    seeds: list[int]
    coarse_mean: list[float | None]
    fine_mean: list[float | None]
    shift_mse: float | None
    chi2: float | None
    seconds: float

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> GrainShift:
        return cls(**dict(data, size_scales=tuple(data["size_scales"])))


def debiased_squares(coarse: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """[K] the squared move of the mean curve from the runs coarse [R_c, K] to fine [R_f, K], each
    less the scatter of the two means (sample variance / R; 0 with one run), not below 0."""
    move = fine.mean(axis=0) - coarse.mean(axis=0)
    scatter = sum(runs.var(axis=0, ddof=1) / len(runs) if len(runs) > 1 else 0.0 for runs in (coarse, fine))
    return np.maximum(move**2 - scatter, 0.0)


def grain_shift(
    model: Model,
    column: MeasuredColumn,
    theta: Sequence[float],
    coarse: SimulationSettings,
    fine_size_scale: float,
    runout: RunoutMethod,
    dem_config: dict | None,
    noise: Sequence[float],
    n_packings: int = 2,
    progress: Callable[[float], None] | None = None,
) -> GrainShift:
    """`model` at theta [p] on `column` at the `coarse` settings' grain size and at fine_size_scale,
    on n_packings packings each (seeds VALIDATION_SEED0 + k), and the move between them (module
    docstring) in units of noise [K] (the data's noise std at the measured times)."""
    started = time.perf_counter()
    runs = []
    for k, settings in enumerate((coarse, replace(coarse, size_scale=float(fine_size_scale)))):
        within = None if progress is None else (lambda f, k=k: progress((k + f) / 2))
        label = f"{model.name} at size_scale {settings.size_scale:g}"
        runs.append(validate(label, model, column, theta, settings, runout, dem_config, n_packings, progress=within))
    coarse_runs, fine_runs = (np.array([c for c in v.curves if c is not None], float) for v in runs)
    means = [list(v.mean) if v.n_ran else [None] * len(column.runout) for v in runs]
    shift_mse = chi2 = None
    if len(coarse_runs) and len(fine_runs):
        squares = debiased_squares(coarse_runs, fine_runs)
        shift_mse = float(np.mean(squares))
        chi2 = float(np.sum(squares / np.square(np.asarray(noise, float))))
    return GrainShift(
        size_scales=(float(coarse.size_scale), float(fine_size_scale)),
        seeds=[VALIDATION_SEED0 + k for k in range(n_packings)],
        coarse_mean=[None if m is None or not math.isfinite(m) else float(m) for m in means[0]],
        fine_mean=[None if m is None or not math.isfinite(m) else float(m) for m in means[1]],
        shift_mse=shift_mse,
        chi2=chi2,
        seconds=time.perf_counter() - started,
    )
