"""A campaign as a DAG stage (workflow/rules/campaign.smk): a `measured` entry of several columns of
one material calibrated as one parameter set by each route (calibration/campaign.py,
doe/campaign_study.py), each column predicted from the others, and the answer with its figure.

Jobs: `run_campaign_route` (rule campaign_route: one route, results/campaign/<name>/<route>.json and
its figure; the GNS route's search on the GNS of the campaign's dataset: `gns_search`) and
`run_campaign` (rule campaign: campaign.json, the answer, and campaign.png, every column's measured
points against the answer's packing band and its held-out prediction's).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from calibration.bayesopt import BOSettings
from calibration.calibrated import read_model
from calibration.campaign import (
    Campaign,
    CampaignBO,
    CampaignRoute,
    CampaignRunner,
    campaign_bayesopt,
    campaign_search,
    route_answer,
)
from calibration.compare import plot_bayesopt
from calibration.design_runs import SimulationSettings
from calibration.measured import read_measured
from calibration.measured_column import MeasuredColumn
from dem.atomic import StrPath, write_json
from dem.progress import progress_logger
from dem.run_store import keeps_runs
from dem.runout import RunoutMethod
from doe.campaign_study import campaign_doe, campaign_surface, column_costs
from doe.plots import plot_surface_pairs
from pipeline.benchmarks import benchmark_seconds

log = logging.getLogger(__name__)

# route key: in words
ROUTES = {"doe": "DoE (face-centred CCD, quadratic)", "bayesopt": "BO on DEM", "gns": "BO on the campaign's GNS"}
MIN_PACKINGS = 4  # a held-out column's prediction runs on at least this many packings


def read_campaign(measured_path: StrPath, name: str) -> Campaign:
    """The campaign of `measured` entry `name`: the columns of its CSV, in file order."""
    return Campaign(name, tuple(read_measured(measured_path).values()))


def campaign_runner(
    measured_path: StrPath,
    model_path: StrPath,
    diagnosis_section: dict,
    *,
    runout: dict | None,
    dem: dict | None,
    name: str,
) -> CampaignRunner:
    """The campaign of `name` and how its model (model.json) runs: at the diagnosis' size_scale (a
    fitted mechanism is an effective value of that grain size), each column read as its file says,
    else by the config's `runout`."""
    campaign = read_campaign(measured_path, name)
    model, why = read_model(model_path, diagnosis_section["channel_width"])
    log.info("%s: %s model (%s); %s", name, model.name, why, campaign.weighting)
    return CampaignRunner(
        campaign,
        model,
        SimulationSettings(size_scale=diagnosis_section["size_scale"]),
        RunoutMethod.from_config(runout),
        dem,
    )


@keeps_runs("out_json")
def run_campaign_route(
    runner: CampaignRunner,
    route: str,
    out_json: StrPath,
    out_figure: StrPath,
    section: dict,
    gns: dict | None = None,
) -> CampaignRoute:
    """One route's answer for the campaign (workflow rule campaign_route): calibrated on every column,
    validated on each, each column predicted from the others, on max(MIN_PACKINGS,
    calibration.validation_packings) packings -> <route>.json (CampaignRoute) and the route's figure.

    section: the config's `calibration` (doe_centre_replicates; budget, n_initial; gns_budget,
    gns_n_initial; seed; campaign_geometry). gns (route "gns"): gns_search's model_path,
    metadata_path, dataset_paths, cost_files and threads."""
    if route not in ROUTES:
        raise ValueError(f"campaign route {route!r}: one of {list(ROUTES)}")
    campaign, model = runner.campaign, runner.model
    label = ROUTES[route]
    progress = progress_logger(f"{campaign.name}: {model.name} model, {label}, {len(campaign.columns)} columns", log)
    started = time.perf_counter()
    added_column, added_why, surrogate = None, "", None
    title = f"{campaign.name}: {label}, campaign objective"
    if route == "doe":
        responses = campaign_doe(runner, section.get("doe_centre_replicates", 3), section.get("seed", 0), progress)
        dem_runs, seconds = column_costs(responses, campaign)

        def optimum_on(columns):
            return campaign_surface(responses, runner, columns)[0]

        _, fit, runs = campaign_surface(responses, runner, campaign.column_names)
        plot_surface_pairs(fit, runs, out_figure, title=title)
    else:
        if route == "gns":
            bo, surrogate = gns_search(runner, section, progress=progress, **(gns or {}))
            dem_runs, search = surrogate.dataset_runs, float(np.sum(bo.seconds))
            seconds = search + surrogate.seconds
            given = campaign.name in section.get("campaign_geometry", {})
            added_column, added_why = surrogate.added_column(len(campaign.columns), search, given)
        else:
            bo = campaign_bayesopt(runner, section["budget"], section["n_initial"], section.get("seed", 0), progress)
            dem_runs = bo.history.n_calls * len(campaign.columns)
            seconds = float(np.sum(bo.seconds))

        def optimum_on(columns):
            return bo.optimum(campaign, columns)

        plot_bayesopt(bo.history.to_dict(), out_figure, title=title)
    log.info("%s: %s calibrated in %d DEM runs, %.0f s", campaign.name, label, dem_runs, time.perf_counter() - started)
    packings = max(MIN_PACKINGS, section["validation_packings"])
    result = route_answer(
        runner,
        label,
        optimum_on,
        packings,
        dem_runs,
        seconds,
        progress_logger(f"{label}: validations", log),
        added_column,
        added_why,
        surrogate.seconds if surrogate else 0.0,
    )
    write_json(out_json, result.to_dict())
    return result


@dataclass(frozen=True)
class SurrogateCost:
    """What the GNS route spends before its search: its dataset's DEM runs and the training of its GNS."""

    dataset_runs: int
    dataset_seconds: float  # wall time of the dataset's jobs: every run's settle and collapse, its metadata (s)
    training_seconds: float  # wall time of its GNS's training job (s)

    @property
    def seconds(self) -> float:
        return self.dataset_seconds + self.training_seconds

    def added_column(
        self, n_columns: int, search_seconds: float, geometry_given: bool
    ) -> tuple[tuple[float, float], str]:
        """((DEM runs, seconds) one more column adds, why): the search's share per column, and where
        the dataset cycles through the campaign's columns (geometry not given by hand) the cases
        that move to another column when one is appended (case k on column k mod C), run anew, and
        a new training."""
        share = search_seconds / n_columns
        if geometry_given:
            why = "on the dataset's given geometries (calibration.campaign_geometry) it adds no run and no training"
            return (0.0, share), why
        if self.dataset_runs <= n_columns:
            why = (
                f"the dataset's {self.dataset_runs} cases leave none for another column: raise calibration.gns_cases "
                "(its dataset is run anew and its GNS trained again)"
            )
            return (0.0, share), why
        moved = sum(k % n_columns != k % (n_columns + 1) for k in range(self.dataset_runs))
        seconds = moved / self.dataset_runs * self.dataset_seconds + self.training_seconds + share
        why = (
            f"the dataset cycles through the campaign's columns: an added column moves {moved} of its "
            f"{self.dataset_runs} cases, run anew, and the GNS is trained again (calibration.campaign_geometry "
            "fixes the dataset's geometries)"
        )
        return (float(moved), seconds), why


def gns_search(
    runner: CampaignRunner,
    section: dict,
    *,
    model_path: StrPath,
    metadata_path: StrPath,
    dataset_paths: Sequence[StrPath],
    cost_files: dict[str, Sequence[StrPath]] | None = None,
    threads: int | None = None,
    progress: Callable[[float], None] | None = None,
) -> tuple[CampaignBO, SurrogateCost]:
    """The GNS route's search: the GNS trained on the campaign's dataset (its cases cycle through the
    columns, pipeline.cases.campaign_templates), one GNS objective per column rolled out from the
    first frames of that column's dataset runs (their mean L*: calibration.gns_objective), and the
    Bayesian optimisation of the campaign objective over the model's box within the range the GNS
    was trained on (calibration.gns_budget,
    gns_n_initial points, one rollout per column each). Returns (its points, what the dataset's DEM
    runs and the training of the GNS cost, summed from the benchmark files of their jobs, cost_files
    {"gns_dataset": [...], "gns_training": [...]}: seconds NaN without them)."""
    import torch

    from calibration.gns_objective import GNSObjective
    from dem.trajectory import read_trajectory
    from gns.dataset import read_metadata
    from gns.simulator import load_simulator

    if threads:
        torch.set_num_threads(threads)
    metadata = read_metadata(metadata_path)
    simulator = load_simulator(model_path, metadata)
    # the GNS answers only inside the range its dataset spans (a rollout outside it is refused)
    trained = metadata["parameter_ranges"]
    bounds = np.array(
        [
            [max(low, trained[name][0]), min(high, trained[name][1])]
            for name, (low, high) in zip(runner.model.parameter_names, runner.model.bounds)
        ]
    )
    runs = [read_trajectory(path) for path in dataset_paths]
    objectives = []
    for column in runner.campaign.columns:
        starts = [
            run
            for run in runs
            if math.isclose(float(run.attrs["L_i"]), column.L_i, rel_tol=1e-9)
            and math.isclose(float(run.attrs["H_i"]), column.H_i, rel_tol=1e-9)
        ]
        if not starts:
            raise ValueError(f"{metadata_path}: no run of the campaign's dataset is of column {column.name!r}")
        objectives.append(
            GNSObjective(
                simulator,
                starts,
                column,
                design_names=runner.model.parameter_names,
                runout=column.runout_reading(runner.runout),
            )
        )

    def evaluate(theta):
        mse, seconds, failures = [], [], []
        for objective in objectives:
            started = time.perf_counter()
            value = float(objective.values(np.asarray(theta)[None], allow_failed=True)[0])
            seconds.append(time.perf_counter() - started)
            mse.append(value)
            failures.append("" if math.isfinite(value) else "the GNS rollout failed or its objective is not finite")
        return mse, seconds, failures

    settings = BOSettings(budget=section["gns_budget"], n_initial=section["gns_n_initial"], seed=section.get("seed", 0))
    bo = campaign_search(runner.campaign, evaluate, bounds, runner.model.parameter_names, settings, progress)
    seconds = {k: benchmark_seconds(v)[0] for k, v in cost_files.items()} if cost_files else {}
    cost = SurrogateCost(len(runs), seconds.get("gns_dataset", math.nan), seconds.get("gns_training", math.nan))
    return bo, cost


@dataclass(frozen=True)
class CampaignResult:
    """A campaign's answer: its routes side by side, the answer the route that predicts held-out
    columns best (the lowest campaign objective of its held-out predictions), at its optimum on all
    columns: a route is judged by what it predicts, not by what it fits."""

    name: str
    measured: str
    columns: list[str]
    aspect_ratios: list[float]
    L_i: list[float]  # m
    weighting: str
    answer: str  # the answer's route
    routes: list[CampaignRoute]

    @property
    def answer_route(self) -> CampaignRoute:
        return next(r for r in self.routes if r.route == self.answer)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def read(cls, path: StrPath) -> CampaignResult:
        data = json.loads(Path(path).read_text())
        return cls(**{**data, "routes": [CampaignRoute.from_dict(r) for r in data["routes"]]})


def run_campaign(
    route_paths: Sequence[StrPath], measured_path: StrPath, name: str, out_json: StrPath, out_figure: StrPath
) -> CampaignResult:
    """The campaign's answer from its routes' results (workflow rule campaign) -> campaign.json and
    campaign.png."""
    campaign = read_campaign(measured_path, name)
    routes = [CampaignRoute.from_dict(json.loads(Path(path).read_text())) for path in route_paths]
    best = min(routes, key=lambda r: (not np.isfinite(r.held_out_mse), r.held_out_mse))
    result = CampaignResult(
        name=name,
        measured=str(measured_path),
        columns=campaign.column_names,
        aspect_ratios=[c.aspect_ratio for c in campaign.columns],
        L_i=[c.L_i for c in campaign.columns],
        weighting=campaign.weighting,
        answer=best.route,
        routes=routes,
    )
    write_json(out_json, result.to_dict())
    plot_campaign(result, campaign.columns, out_figure)
    return result


def plot_campaign(result: CampaignResult, columns: Sequence[MeasuredColumn], path: StrPath) -> None:
    """One panel per column: its measured L* (with the stated std), the answer's validated mean
    curve and packing band (+- one std over the packings), and the column predicted from the others
    (the answer's route calibrated without it), its band dashed."""
    from dem.plots import plt, save_figure

    answer = result.answer_route
    fig, axes = plt.subplots(1, len(columns), figsize=(4.2 * len(columns), 3.8), squeeze=False)
    for ax, column, validation, held in zip(axes[0], columns, answer.validations, answer.held_out, strict=True):
        t = np.asarray(column.t_over_tstar)
        for run, style, label in (
            (validation, "-", f"all columns: MSE {validation.mse:.3g}"),
            (held.validation, "--", f"from the others: MSE {held.validation.mse:.3g}"),
        ):
            mean, std = np.asarray(run.mean), np.asarray(run.std)
            (line,) = ax.plot(t, mean, style, label=label)
            ax.fill_between(t, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        yerr = None if column.runout_std is None else column.runout_std
        ax.errorbar(t, column.runout, yerr=yerr, fmt="ko", ms=4, label="measured")
        ax.set_title(f"{column.name}: a = {column.aspect_ratio:g}, L_i = {column.L_i * 1e3:g} mm", fontsize=9)
        ax.set_xlabel("t / t*")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("L* = (L - L_i) / L_i")
    n_packings = len(answer.validations[0].seeds)
    fig.suptitle(
        f"{result.name}: the {answer.model} model by {answer.route}, {n_packings} packings per band", fontsize=10
    )
    save_figure(fig, path)
