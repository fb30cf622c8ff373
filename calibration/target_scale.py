"""The answer carried to the resolution the engineer will simulate (multi-fidelity): calibrated on
coarse grains, corrected by a few DEM runs at the target size_scale.

A coarse-grained calibration gives effective parameters of its scale: the finer the grains, the
farther the same column runs (docs/experiments/grain-size.md: L* at 4 t* 13% higher at size_scale
3 than at 5), so the coarse answer misses at the target by more than the fit it was chosen on.
What changes less between the scales is which way the curve responds to each parameter. So the coarse
DEM measures the slopes of L* in the parameters (a star design about the coarse answer, cheap at
the coarse scale) and the target DEM only the level: Gauss-Newton steps of the target's own
residual along those slopes, damped by the packing noise and bounded by a trust region
(calibration.confirmation.refine, an output space mapping: the shape from the coarse model, the
level from the fine one). The coarse slopes point the right way but their size is the coarse
scale's, so each step updates them by the secant (Broyden) rule from what the target DEM answered;
without it the steps overshot and undershot in turn (docs/experiments/target-scale.md). The point
the target DEM scores lowest on its correction packings is then validated at the target on the
validation packings, which neither scale calibrated on.

The answer one scale finer, with no run there (`predict_finer`): the target's parameters are
effective values of its grain size too, since this model's runout keeps growing as its grains get
finer, down to real grains (docs/experiments/grain-size.md). The move of the mean curve from the
coarse scale to the target at the coarse answer, on the same packings (the star's centre and the
correction's start), is measured here anyway; taken as linear in log grain size, a fraction
ln(target / finer) / ln(coarse / target) of it is expected from the target to the finer scale, and
one more damped Gauss-Newton step along the target's slopes answers it. The
engineer who runs the finer scale takes those parameters; the pipeline validates them there, held
out (docs/experiments/target-scale.md).

Cost: (2p + 1) x packings coarse runs for the slopes, (1 + rounds) x packings + validation runs at
the target, against a whole calibration at the target.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from calibration.calibrated import Validation, buildable_cases, validate
from calibration.confirmation import CONFIRM_SEED0, TRUST_RADIUS, Confirmation, damped_step, local_slope, refine
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from dem.atomic import StrPath
from dem.run_ahead import run_ahead
from dem.runout import RunoutMethod

# The star's arm in the unit box: long enough that a slope stands above the packing noise of the
# coarse mean curve, short enough to stay on the local slope (the GNS route's SLOPE_BANDWIDTH is 0.15).
STAR_STEP = 0.1


@dataclass
class TargetCalibration:
    """The answer at the target size_scale.

    size_scale: the target's coarse-graining factor; coarse_size_scale: the calibration's.
    slopes [2p + 1]: the coarse star design's points about the coarse answer (Validation each, on
    the correction packings); correction: the coarse answer run at the target (its one candidate)
    and the Gauss-Newton steps (calibration.confirmation.Confirmation, chosen: the lowest target MSE);
    validation: the chosen point at the target on the validation packings (5001, ...), none of which
    calibrated; seconds: wall time of all of it.
    """

    size_scale: float
    coarse_size_scale: float
    slopes: list[Validation]
    correction: Confirmation
    validation: Validation
    seconds: float
    finer: FinerScale | None = None

    @property
    def theta(self) -> list[float]:
        """The answer at the target [p], in the model's order."""
        return list(self.validation.parameters.values())

    @property
    def coarse_runs(self) -> int:
        return sum(len(v.seeds) for v in self.slopes)

    @property
    def target_runs(self) -> int:
        return self.correction.dem_runs + len(self.validation.seeds)

    def to_dict(self) -> dict:
        """JSON: the scales, the slope points (parameters, seeds, mean L* curve, mse), the correction
        (Confirmation.to_dict), the validation (Validation.to_dict), the DEM runs and seconds at each
        scale."""
        slopes = [{k: asdict(v)[k] for k in ("parameters", "seeds", "mean", "mse", "seconds")} for v in self.slopes]
        return {
            "size_scale": self.size_scale,
            "coarse_size_scale": self.coarse_size_scale,
            "slopes": slopes,
            "correction": self.correction.to_dict(),
            "validation": self.validation.to_dict(),
            "coarse_runs": self.coarse_runs,
            "coarse_seconds": sum(v.seconds for v in self.slopes),
            "target_runs": self.target_runs,
            "target_seconds": self.correction.seconds + self.validation.seconds,
            "seconds": self.seconds,
            "finer": None if self.finer is None else asdict(self.finer),
        }


@dataclass
class FinerScale:
    """The answer predicted for a finer size_scale from the two scales the carrying ran, with no run
    at the finer one (the module's docstring).

    size_scale: the finer scale; factor: ln(target / finer) / ln(coarse / target), the share of the
    coarse-to-target move expected from the target to the finer scale; shift [K]: the mean L*
    curve's move from the coarse scale to the target at the coarse answer on the same packings,
    shift_mse its mean square (L*^2); predicted [K]: the target answer's mean curve plus factor x
    shift, moved by the step along the target's slopes; predicted_mse: its MSE against the measured
    curve; parameters: {name: value} for the finer scale, in the model's order.
    """

    size_scale: float
    factor: float
    shift: list[float]
    shift_mse: float
    predicted: list[float]
    predicted_mse: float
    parameters: dict[str, float]

    @property
    def theta(self) -> list[float]:
        return list(self.parameters.values())


def predict_finer(
    model: Model,
    column: MeasuredColumn,
    slopes: Sequence[Validation],
    correction: Confirmation,
    coarse_size_scale: float,
    target_size_scale: float,
    finer_size_scale: float,
) -> FinerScale | None:
    """The answer for finer_size_scale (FinerScale) from the star `slopes` at the coarse scale and
    the `correction` at the target (calibrate_at_target's); None where the shift or the slope is
    unknown (a failed run at the star's centre or the start, fewer than p + 1 star points)."""
    start, chosen = correction.candidates[0], correction.checked[correction.chosen]
    shift = np.asarray(start.mean, float) - np.asarray(slopes[0].mean, float)
    if not (np.all(np.isfinite(shift)) and math.isfinite(chosen.mse)):
        return None
    centre = model.box.to_unit(list(chosen.parameters.values()))[0]
    slope = correction.slope
    if slope is None:  # no refinement ran: the coarse star's own slope
        ran = [v for v in slopes if math.isfinite(v.mse)]
        if len(ran) <= model.n_parameters:
            return None
        points = model.box.to_unit(np.array([list(v.parameters.values()) for v in ran]))
        slope = local_slope(points, np.array([v.mean for v in ran], float), centre)
    factor = math.log(target_size_scale / finer_size_scale) / math.log(coarse_size_scale / target_size_scale)
    measured = np.asarray(column.runout, float)
    expected = np.asarray(chosen.mean, float) + factor * shift  # the target answer's curve at the finer scale
    move = damped_step(slope, measured - expected, centre, TRUST_RADIUS, chosen)
    predicted = expected + slope @ move
    theta = model.box.from_unit(centre + move)[0]
    return FinerScale(
        size_scale=float(finer_size_scale),
        factor=factor,
        shift=shift.tolist(),
        shift_mse=float(np.mean(shift**2)),
        predicted=predicted.tolist(),
        predicted_mse=float(np.mean((measured - predicted) ** 2)),
        parameters=dict(zip(model.parameter_names, map(float, theta))),
    )


def star_points(model: Model, theta: Sequence[float], step: float = STAR_STEP) -> np.ndarray:
    """[2p + 1, p] theta and theta +- step along each parameter in the model's unit box (log axes
    where it has them), clipped to the box: at a bound the arm on that side is the centre itself."""
    centre = model.box.to_unit(np.asarray(theta, float))[0]
    arms = [centre]
    for i in range(len(centre)):
        for sign in (-1.0, 1.0):
            point = centre.copy()
            point[i] = min(max(centre[i] + sign * step, 0.0), 1.0)
            arms.append(point)
    return model.box.from_unit(np.array(arms))


def run_star(
    model: Model,
    column: MeasuredColumn,
    points: np.ndarray,
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_packings: int,
    label: str,
    part: Callable[[float, float], Callable[[float], None] | None],
) -> list[Validation]:
    """Each star point [n, p] (star_points) run at `settings` on n_packings confirmation packings
    (CONFIRM_SEED0 + k); label: each run's name, "{k}" the point's index; part(offset, width): the
    progress callable of the runs from offset to offset + width, in packings' worth of runs."""
    own = {"seed0": CONFIRM_SEED0, "made_ahead": True}  # the whole star is made ahead here
    seeds = [CONFIRM_SEED0 + k for k in range(n_packings)]
    run_ahead(
        buildable_cases(model, column, points, settings, seeds), dem_config, label.format(k=f"0-{len(points) - 1}")
    )
    return [
        validate(
            label.format(k=k),
            model,
            column,
            point,
            settings,
            runout,
            dem_config,
            n_packings,
            **own,
            progress=part(k * n_packings, n_packings),
        )
        for k, point in enumerate(points)
    ]


def secant_steps(
    model: Model,
    column: MeasuredColumn,
    start: Validation,
    points: np.ndarray,
    star: Sequence[Validation],
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_rounds: int,
    progress: Callable[[float], None] | None = None,
) -> Confirmation:
    """`start` (a Validation at `settings`) corrected by n_rounds Gauss-Newton steps of the DEM at
    `settings` along the slopes of the star's mean curves (star: run_star of points [n, p]),
    updated by the secant rule (calibration.confirmation.refine); the star's centre, star[0], is
    the start's surrogate value. No step where fewer than p + 1 star points ran."""
    correction = Confirmation([start], [star[0].mse], 0)
    ran = [i for i, v in enumerate(star) if math.isfinite(v.mse)]
    if len(ran) > model.n_parameters and n_rounds > 0:  # a slope in p parameters needs p + 1 points
        means = np.array([star[i].mean for i in ran], float)
        own = {"progress": progress, "secant": True}
        correction = refine(
            model, column, correction, points[ran], means, settings, runout, dem_config, n_rounds, **own
        )
    return correction


def resolution_shift(
    coarse_mean: Sequence[float | None], fine_mean: Sequence[float | None], fit_mse: float
) -> tuple[float | None, float | None]:
    """How far the model's own mean L* curve [T] moves between two grain sizes at the same parameters
    and packing seeds: (its MSE, the least transfer MSE it allows). By the triangle inequality of the
    RMS, a curve that misses the measured one by fit_mse at the coarser size misses it by at least
    (sqrt(shift) - sqrt(fit_mse))^2 at the finer: a fit better than the shift cannot transfer as well
    as it fits. (None, None) where no time has both means."""
    pairs = [(c, f) for c, f in zip(coarse_mean, fine_mean, strict=True) if c is not None and f is not None]
    pairs = [(c, f) for c, f in pairs if math.isfinite(c) and math.isfinite(f)]
    if not pairs:
        return None, None
    shift = float(np.mean([(f - c) ** 2 for c, f in pairs]))
    return shift, (math.sqrt(shift) - math.sqrt(fit_mse)) ** 2


def calibrate_at_target(
    model: Model,
    column: MeasuredColumn,
    theta: Sequence[float],
    coarse: SimulationSettings,
    target_size_scale: float,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_packings: int,
    n_validation: int,
    n_rounds: int,
    progress: Callable[[float], None] | None = None,
    finer_size_scale: float | None = None,
) -> TargetCalibration:
    """The coarse answer theta [p] (found at `coarse` settings) corrected at target_size_scale (the
    module's docstring): the star design at the coarse scale and the correction at the target on
    n_packings packings (CONFIRM_SEED0 + k) each, n_rounds Gauss-Newton steps, then the lowest
    validated at the target on n_validation packings; with finer_size_scale, the answer predicted
    for it too (predict_finer, no run)."""
    started = time.perf_counter()
    target = replace(coarse, size_scale=float(target_size_scale))
    points = star_points(model, theta)
    # progress in packings' worth of runs: the star, the start and steps, the validation
    total = (len(points) + 1 + n_rounds) * n_packings + n_validation

    def part(offset: float, width: float) -> Callable[[float], None] | None:
        return None if progress is None else (lambda f: progress(min((offset + f * width) / total, 1.0)))

    label = f"slope point {{k}} at size_scale {coarse.size_scale:g}"
    slopes = run_star(model, column, points, coarse, runout, dem_config, n_packings, label, part)
    done = len(points) * n_packings
    label = f"the coarse answer at size_scale {target.size_scale:g}"
    within = part(done, n_packings)
    own = {"progress": within, "seed0": CONFIRM_SEED0}
    start = validate(label, model, column, theta, target, runout, dem_config, n_packings, **own)
    # the coarse DEM is the surrogate here: its value at the start, the star's centre on the same packings
    within = part(done + n_packings, n_rounds * n_packings)
    correction = secant_steps(model, column, start, points, slopes, target, runout, dem_config, n_rounds, within)
    chosen = correction.checked[correction.chosen]
    label = f"the answer at size_scale {target.size_scale:g}"
    within = part(total - n_validation, n_validation)
    theta_target = list(chosen.parameters.values())
    validation = validate(label, model, column, theta_target, target, runout, dem_config, n_validation, progress=within)
    finer = None
    if finer_size_scale:
        finer = predict_finer(model, column, slopes, correction, coarse.size_scale, target.size_scale, finer_size_scale)
    seconds = time.perf_counter() - started
    return TargetCalibration(
        target.size_scale, float(coarse.size_scale), slopes, correction, validation, seconds, finer
    )


def plot_scales(
    column: MeasuredColumn,
    answer: dict,
    coarse_size_scale: float,
    target: dict | None,
    transfer: dict | None,
    path: StrPath,
) -> None:
    """The answer across scales: the measured points; the answer at the calibration's scale (its
    validation: `answer`, a Validation dict), at the target before and after the correction
    (`target`, TargetCalibration.to_dict(); None: no target) and the held-out transfer (`transfer`,
    a Validation dict with its size_scale, at the parameters predicted for it where target["finer"]
    holds them; None: not run), each the mean of its `curves` [R][K] at
    the column's times with its packing band (+- one std)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.plots import save_figure

    curves = [(answer, f"the answer at size_scale {coarse_size_scale:g}", "tab:blue")]
    if target:
        start = target["correction"]["candidates"][0]
        fine = f"size_scale {target['size_scale']:g}"
        curves += [
            (start, f"the same at {fine}", "tab:red"),
            (target["validation"], f"corrected at {fine}", "tab:green"),
        ]
    if transfer:
        predicted = "predicted parameters, " if target and target.get("finer") else ""
        curves.append((transfer, f"{predicted}held out at size_scale {transfer['size_scale']:g}", "tab:purple"))
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for record, label, colour in curves:
        ran = np.array([c for c in record["curves"] if c is not None], float).reshape(-1, len(column.runout))
        if not len(ran):
            continue
        t, mean, std = column.t_over_tstar, ran.mean(axis=0), ran.std(axis=0, ddof=1) if len(ran) > 1 else None
        if std is not None:
            ax.fill_between(t, mean - std, mean + std, color=colour, alpha=0.15)
        mse = record["mse"] if record["mse"] is not None else math.nan
        ax.plot(t, mean, color=colour, lw=2, label=f"{label}: MSE {mse:.3g} ({len(record['seeds'])} packings)")
    ax.plot(column.t_over_tstar, column.runout, "ko", ms=6, label=f"measured ({column.name})")
    ax.set(xlabel="t / t*", ylabel="L* = (L - L_i) / L_i", title="the answer across grain sizes")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)
