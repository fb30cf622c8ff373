"""A lab campaign: several measured columns of one material calibrated as one parameter set, and
each column predicted from the others.

A campaign's objective is the weighted mean of its columns' runout MSEs (`Campaign.objective`):
weights 1 / (mean stated variance of the column's L*) where every column states its std, else equal
(a column without a stated noise cannot be weighed against one with). The routes that calibrate a
campaign run every parameter point on every column: the DoE (doe/campaign_study.py) every design
point, the Bayesian optimisation (`campaign_search`) one DEM run (`campaign_bayesopt`, on one
packing) or one GNS rollout (pipeline.campaign.gns_search) per column per point.

Leave one column out (`held_out_optimum`): calibrate on the rest, then predict the held-out column
with DEM on several packings (`calibration.calibrated.validate`) and compare its MSE with the
column's packing scatter (`scatter_bound`): a prediction that misses a column by no more than one
packing differs from another, plus the data's own noise, is as good as the DEM can say. The routes
reuse their own runs for the rest's calibration (the DoE refits its surface to the rest's columns;
the BO takes its best point on the rest's objective), so holding a column out costs only its
validation runs. The answer is the route whose held-out predictions are best (`held_out_mse`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from calibration.bayesopt import BOSettings, bayesian_optimisation
from calibration.calibrated import CALIBRATION_SEED, Validation, model_runout, validate
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.objective import runout_mse
from calibration.optimise import OptimisationHistory, PointFailed, one_at_a_time
from dem.engines import FAILURES, failure_reason
from dem.runout import RunoutMethod

log = logging.getLogger(__name__)


class CampaignError(ValueError):
    """A campaign that cannot be calibrated as one parameter set (the message names the file and column)."""


@dataclass(frozen=True)
class Campaign:
    """The columns of one `measured` entry, of one material, in the file's order."""

    name: str  # the config's name of the measured entry
    columns: tuple[MeasuredColumn, ...]

    def __post_init__(self):
        if len(self.columns) < 2:
            raise CampaignError(f"campaign {self.name!r}: {len(self.columns)} column(s); a campaign holds 2 or more")
        names = [c.name for c in self.columns]
        if len(set(names)) < len(names):
            raise CampaignError(f"campaign {self.name!r}: two columns of the same name in {names}")
        first = self.columns[0]
        for column in self.columns[1:]:
            if column.material_properties != first.material_properties:
                raise CampaignError(
                    f"{column.source}: column {column.name!r} is of material {column.material!r}, column "
                    f"{first.name!r} of {first.material!r}: one campaign calibrates one material"
                )

    @property
    def column_names(self) -> list[str]:
        return [c.name for c in self.columns]

    @property
    def weights_stated(self) -> bool:
        """Whether every column states the noise of its runout (then the weights follow it)."""
        return all(c.runout_std is not None for c in self.columns)

    @property
    def weights(self) -> np.ndarray:
        """[C] weight of each column's MSE, mean 1: 1 / mean(std^2) where every column states its
        std, else equal."""
        if not self.weights_stated:
            return np.ones(len(self.columns))
        inverse = np.array([1.0 / float(np.mean(np.square(c.runout_std))) for c in self.columns])
        return inverse / inverse.mean()

    @property
    def weighting(self) -> str:
        """How the columns are weighed, in words."""
        if self.weights_stated:
            pairs = ", ".join(f"{c.name} {w:.3g}" for c, w in zip(self.columns, self.weights))
            return f"weighted by 1 / the stated variance of L* ({pairs})"
        return "equal weights (not every column states the noise of its runout)"

    def index(self, column: str) -> int:
        return self.column_names.index(column)

    def objective(self, mse: Sequence[float], columns: Sequence[str] | None = None) -> float:
        """The weighted mean of per-column MSEs mse [C] (in the campaign's column order) over
        `columns` (None: all); NaN where one of them is NaN (a run that failed)."""
        keep = [self.index(c) for c in (self.column_names if columns is None else columns)]
        values = np.asarray(mse, float)[keep]
        weights = self.weights[keep]
        return float(np.sum(weights * values) / np.sum(weights))

    def others(self, column: str) -> list[str]:
        """Every column's name but `column`'s."""
        return [c for c in self.column_names if c != column]


@dataclass(frozen=True)
class CampaignOptimum:
    """What a route found on a set of columns: parameters and the campaign objective there as the
    route saw it (its surface's prediction, or its best run)."""

    columns: list[str]  # the columns calibrated on
    parameters: dict[str, float]
    objective: float  # weighted runout MSE (-) on those columns, as the route saw it

    @property
    def theta(self) -> list[float]:
        return list(self.parameters.values())


@dataclass(frozen=True)
class HeldOut:
    """One column predicted from the others: the route's optimum on the rest, run on the held-out
    column on several packings."""

    column: str
    optimum: CampaignOptimum  # calibrated on the other columns
    validation: Validation  # the held-out column at that optimum
    scatter_bound: float  # the MSE a prediction as good as the packing scatter stays under (scatter_bound)

    @property
    def within_scatter(self) -> bool:
        return bool(self.validation.mse <= self.scatter_bound)


@dataclass(frozen=True)
class CampaignRoute:
    """One route's answer for a campaign: its optimum on all columns, validated on every column,
    and each column predicted from the others."""

    name: str
    route: str
    model: str
    parameter_names: list[str]
    weighting: str
    optimum: CampaignOptimum
    validations: list[Validation]  # [C] every column at the optimum, validation packings
    mse: float  # the campaign objective of the validated mean curves
    mse_se: float | None  # its standard error from the columns' jackknife errors (None: some lack one)
    held_out: list[HeldOut]  # [C] leave-one-column-out
    held_out_mse: float  # the campaign objective of the held-out predictions: how well the route predicts
    dem_runs: int  # calibration runs, all columns (the GNS route: its dataset's)
    seconds: float  # calibration wall time (the GNS route: its dataset's runs, its training and its search)
    runs_per_column: float  # DEM runs an added column costs this route's calibration
    seconds_per_column: float  # the wall time it adds
    validation_seconds: float  # all validations, the held-out ones included
    added_column_why: str = ""  # how the cost of an added column is counted, where not an equal share
    surrogate_seconds: float = 0.0  # within seconds: the GNS route's dataset runs and training

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> dict:
        """The figures a benchmark prints: the optimum, the validated MSE per column and the campaign's,
        each held-out column's MSE against its scatter bound, and the cost."""
        return {
            "route": self.route,
            "optimum": self.optimum.parameters,
            "campaign_mse": self.mse,
            "mse": {h.column: v.mse for h, v in zip(self.held_out, self.validations, strict=True)},
            "held_out": {
                h.column: {"mse": h.validation.mse, "bound": h.scatter_bound, "within": h.within_scatter}
                for h in self.held_out
            },
            "held_out_mse": self.held_out_mse,
            "dem_runs": self.dem_runs,
            "seconds": self.seconds,
            "surrogate_seconds": self.surrogate_seconds,
            "runs_per_added_column": self.runs_per_column,
            "seconds_per_added_column": self.seconds_per_column,
            "added_column": self.added_column_why,
            "validation_seconds": self.validation_seconds,
        }

    @classmethod
    def from_dict(cls, data: dict) -> CampaignRoute:
        def optimum(d):
            return CampaignOptimum(**d)

        def validation(d):
            return Validation(**{**d, "failed": {int(k): v for k, v in d["failed"].items()}})

        return cls(
            **{
                **data,
                "optimum": optimum(data["optimum"]),
                "validations": [validation(v) for v in data["validations"]],
                "held_out": [
                    HeldOut(h["column"], optimum(h["optimum"]), validation(h["validation"]), h["scatter_bound"])
                    for h in data["held_out"]
                ],
            }
        )


# A runout curve's misses are strongly correlated in time (a packing that runs far stays far): its
# MSE behaves like about one degree of freedom of chi^2, whose 95% point is 3.84 times its mean.
SCATTER_LEVEL = 4.0


def scatter_bound(validation: Validation, column: MeasuredColumn) -> float:
    """The runout MSE (-) that a prediction of `column` at the true parameters stays under at a 95%
    level: SCATTER_LEVEL times its expected miss, the packing variance of one run (the measured
    column is one packing; validation.std^2 over its R packings, mean over the measured times) times
    (1 + 1/R) (the predicted mean is of R packings) plus the data's stated variance (0 where none
    is stated). NaN with fewer than 2 packings run."""
    packing = float(np.mean(np.square(validation.std)))
    data = 0.0 if column.runout_std is None else float(np.mean(np.square(column.runout_std)))
    return SCATTER_LEVEL * (packing * (1.0 + 1.0 / max(validation.n_ran, 1)) + data)


def combined_se(campaign: Campaign, validations: Sequence[Validation]) -> float | None:
    """The standard error of the campaign objective of validated mean curves, from each column's
    jackknife error (independent packings per column); None when a column has none."""
    if any(v.mse_se is None for v in validations):
        return None
    weights = campaign.weights
    return float(math.sqrt(np.sum(np.square(weights * [v.mse_se for v in validations]))) / np.sum(weights))


@dataclass(frozen=True)
class CampaignRunner:
    """How a campaign's model is simulated: its model, grains (size_scale), runout reading and engine."""

    campaign: Campaign
    model: Model
    settings: SimulationSettings
    runout: RunoutMethod
    dem: dict | None

    def run_all(self, theta: Sequence[float], seed: int) -> tuple[list[float], list[float], list[str]]:
        """One DEM run per column at theta [p] on packing `seed`: (mse [C] (NaN where the run
        failed), wall time [C] (s), failure reason [C] ("" where it ran))."""
        mse, seconds, failures = [], [], []
        for column in self.campaign.columns:
            started = time.perf_counter()
            try:
                curve = model_runout(self.model, column, theta, self.settings, seed, self.runout, self.dem)
                mse.append(float(runout_mse(curve, column.runout)))
                failures.append("")
            except FAILURES as exc:  # kept with its reason; the point's objective is NaN
                mse.append(math.nan)
                failures.append(failure_reason(exc))
                log.warning("%s at %s failed: %s", column.name, np.round(theta, 4).tolist(), failures[-1])
            seconds.append(time.perf_counter() - started)
        return mse, seconds, failures

    def validate(self, route: str, column: MeasuredColumn, theta: Sequence[float], n_packings: int) -> Validation:
        """`column` at theta on the validation packings (calibration.calibrated.validate)."""
        return validate(route, self.model, column, theta, self.settings, self.runout, self.dem, n_packings)


@dataclass(frozen=True)
class CampaignBO:
    """A Bayesian optimisation's points: the history of the campaign objective and each point's
    per-column MSE."""

    history: OptimisationHistory
    mse: list[list[float]]  # [n][C] per-column MSE of each evaluated point (history.params order)
    seconds: list[list[float]]  # [n][C] wall time of each column's evaluation (s)

    def optimum(self, campaign: Campaign, columns: Sequence[str]) -> CampaignOptimum:
        """The best evaluated point on the objective of `columns` (its own points, re-weighed)."""
        values = [campaign.objective(row, columns) for row in self.mse]
        best = int(np.nanargmin(values))
        return CampaignOptimum(list(columns), dict(zip(self.history.names, self.history.params[best])), values[best])


# One point on every column: (mse [C], wall time [C] (s), failure reason [C], "" where it ran).
ColumnEvaluation = Callable[[np.ndarray], tuple[list[float], list[float], list[str]]]


def campaign_search(
    campaign: Campaign,
    evaluate: ColumnEvaluation,
    bounds: np.ndarray,
    names: Sequence[str],
    settings: BOSettings,
    progress: Callable[[float], None] | None = None,
) -> CampaignBO:
    """GP expected-improvement BO of the campaign objective over `bounds` [p, 2], every point
    evaluated on every column by `evaluate` (DEM runs, or GNS rollouts); a point where one column
    fails is recorded as failed (the GP never sees it)."""
    mse, seconds = [], []

    def objective(theta: np.ndarray) -> float:
        values, times, failures = evaluate(theta)
        if any(failures):
            raise PointFailed("; ".join(f"{c}: {f}" for c, f in zip(campaign.column_names, failures) if f))
        mse.append(values)
        seconds.append(times)
        return campaign.objective(values)

    result = bayesian_optimisation(
        one_at_a_time(objective),
        bounds.tolist(),
        list(names),
        settings,
        progress=None if progress is None else (lambda batch, s, v: progress(batch / settings.budget)),
    )
    return CampaignBO(result.history, mse, seconds)


def campaign_bayesopt(
    runner: CampaignRunner,
    budget: int,
    n_initial: int,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
) -> CampaignBO:
    """The BO on DEM: each point runs every column on packing CALIBRATION_SEED + seed."""
    return campaign_search(
        runner.campaign,
        lambda theta: runner.run_all(theta, CALIBRATION_SEED + seed),
        runner.model.bounds,
        runner.model.parameter_names,
        BOSettings(budget=budget, n_initial=n_initial, seed=seed),
        progress,
    )


def route_answer(
    runner: CampaignRunner,
    route: str,
    optimum_on: Callable[[Sequence[str]], CampaignOptimum],
    n_packings: int,
    dem_runs: int,
    seconds: float,
    progress: Callable[[float], None] | None = None,
    added_column: tuple[float, float] | None = None,
    added_column_why: str = "",
    surrogate_seconds: float = 0.0,
) -> CampaignRoute:
    """A route's answer from its optimum on any set of columns (optimum_on(columns)): the optimum on
    all validated on every column, then each column predicted from the others' optimum, every
    validation on n_packings packings. dem_runs, seconds: what the route's calibration spent;
    added_column: (DEM runs, seconds) one more column would add to it, added_column_why how that is
    counted (None: an equal share, as for a route that runs every point on every column);
    surrogate_seconds: the part of `seconds` spent on a surrogate (the GNS route's dataset and training)."""
    campaign = runner.campaign
    started = time.perf_counter()
    steps = 2 * len(campaign.columns)
    optimum = optimum_on(campaign.column_names)
    validations = []
    for k, column in enumerate(campaign.columns):
        validations.append(runner.validate(route, column, optimum.theta, n_packings))
        if progress is not None:
            progress((k + 1) / steps)
    held_out = []
    for k, column in enumerate(campaign.columns):
        rest = optimum_on(campaign.others(column.name))
        validation = runner.validate(f"{route}, {column.name} held out", column, rest.theta, n_packings)
        held_out.append(HeldOut(column.name, rest, validation, scatter_bound(validation, column)))
        log.info(
            "%s: %s predicted from the others at %s: MSE %.4g (packing scatter %.4g)",
            route,
            column.name,
            {n: round(v, 4) for n, v in rest.parameters.items()},
            validation.mse,
            held_out[-1].scatter_bound,
        )
        if progress is not None:
            progress((len(campaign.columns) + k + 1) / steps)
    n_columns = len(campaign.columns)
    added_runs, added_seconds = added_column or (dem_runs / n_columns, seconds / n_columns)
    return CampaignRoute(
        name=campaign.name,
        route=route,
        model=runner.model.name,
        parameter_names=list(runner.model.parameter_names),
        weighting=campaign.weighting,
        optimum=optimum,
        validations=validations,
        mse=campaign.objective([v.mse for v in validations]),
        held_out_mse=campaign.objective([h.validation.mse for h in held_out]),
        mse_se=combined_se(campaign, validations),
        held_out=held_out,
        dem_runs=dem_runs,
        seconds=seconds,
        runs_per_column=added_runs,
        seconds_per_column=added_seconds,
        validation_seconds=time.perf_counter() - started,
        added_column_why=added_column_why,
        surrogate_seconds=surrogate_seconds,
    )
