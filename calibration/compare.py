"""DEM validation of calibrated parameters and the comparison of the calibration routes (the
paper's Table 5 and Fig. 10), with a third route an engineer would pick instead of a surrogate:
Bayesian optimisation directly on DEM runs (calibration.bayesopt, at most 20 runs).

Every route ends in DEM runs of the measured column at its optimum, scored by THE objective
(calibration.objective) against the measured curve: that validated objective, the number of DEM
runs each route needed, and the wall time it spent (offline: data generation and training;
online: the calibration itself) make the comparison. Times are sums of job wall times (one core
each) from the Snakemake benchmark files, so the routes compare in CPU time; the DoE's and the
GNS dataset's runs are independent and spread over cores, the BO's runs are sequential.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from calibration.bayesopt import BOSettings, bayesian_optimisation
from calibration.measured_column import MeasuredColumn
from calibration.objective import objective
from calibration.optimise import OptimisationHistory, PointFailed, one_at_a_time
from dem.atomic import atomic_path, write_text
from dem.case import CollapseCase, Material
from dem.engines import FAILURES, failure_reason
from dem.runout import RunoutMethod, runout_at
from dem.trajectory import Trajectory
from gns.dataset import read_training_attrs

log = logging.getLogger(__name__)
BO_MAX_RUNS = 20


class ComparisonError(ValueError):
    """A comparison input is missing or inconsistent; the message names the file or field."""


# case fields that say which column and which run it is, not which DEM model
NOT_MODEL_FIELDS = (
    "material",
    "L_i",
    "aspect_ratio",
    "friction",
    "restitution",
    "friction_wall",
    "restitution_wall",
    "friction_base",
    "seed",
    "name",
    "duration_over_tstar",
    "output_interval",
)


def model_case_fields(attrs: dict) -> dict:
    """CollapseCase fields of the DEM model a trajectory was run with (grain size, contact law
    constants, mechanisms), without its column, parameters or seed; output_interval = its dt_frame.

    Wall/base friction and restitution are left to follow the grain values (attrs hold resolved
    values; copying them would pin them when mu and e change).
    """
    fields = {f.name for f in dataclasses.fields(CollapseCase)} - set(NOT_MODEL_FIELDS)
    out = {k: attrs[k] for k in fields if k in attrs}
    out["output_interval"] = float(attrs["dt_frame"])
    for key in ("friction_wall", "restitution_wall", "friction_base"):
        grain = "restitution" if key.startswith("restitution") else "friction"
        if key in attrs and not np.isclose(float(attrs[key]), float(attrs[grain])):
            out[key] = float(attrs[key])  # a wall value set apart from the grain value stays
    return out


def case_like(
    attrs: dict,
    friction: float,
    restitution: float,
    seed: int,
    name: str = "",
    duration_over_tstar: float | None = None,
) -> CollapseCase:
    """The case of a trajectory's column and DEM model at other (mu, e) and packing seed."""
    return CollapseCase(
        material=Material.from_attrs(attrs),
        L_i=float(attrs["L_i"]),
        aspect_ratio=float(attrs["aspect_ratio"]),
        friction=friction,
        restitution=restitution,
        seed=seed,
        name=name,
        duration_over_tstar=float(duration_over_tstar or attrs.get("duration_over_tstar", 4.0)),
        **model_case_fields(attrs),
    )


def measured_case_fields(metadata: dict, seed: int = 0) -> dict:
    """CollapseCase fields for DEM runs of a measured column with the GNS dataset's DEM model
    (grain size, frame interval, contact constants, simulated time), packing `seed`."""
    first = read_training_attrs(metadata)[0]
    return dict(
        model_case_fields(first), seed=int(seed), duration_over_tstar=float(first.get("duration_over_tstar", 4.0))
    )


def dem_run(
    measured: MeasuredColumn,
    params: dict,
    case_fields: dict,
    name: str = "",
    progress: Callable | None = None,
    dem_config: dict | None = None,
) -> Trajectory:
    """DEM collapse of the measured column (its material, a, L_i) at params {name: value}, with the
    engine of dem_config (the workflow's `dem` section; None: builtin).

    case_fields: other CollapseCase fields (size_scale, duration_over_tstar, seed, output_interval).
    """
    from dem.engines import simulate_case

    case = measured.collapse_case(**{k: float(v) for k, v in params.items()}, name=name, **case_fields)
    log.info(
        "DEM run %s: %s, %d grains", name, ", ".join(f"{k}={float(v):.4f}" for k, v in params.items()), case.n_particles
    )
    return simulate_case(case, dem_config, progress=progress)


def validation_summary(trajectory: Trajectory, measured: MeasuredColumn, runout: RunoutMethod) -> dict:
    """Objective and L* (read by `runout`) at the measured t/t* of a DEM run, with its parameters
    and run time."""
    return {
        "mse": objective(trajectory, measured, runout),
        "runout": runout_at(trajectory, measured.t_over_tstar, runout).tolist(),
        "friction": float(trajectory.attrs["friction"]),
        "restitution": float(trajectory.attrs["restitution"]),
        "dem_wall_time_s": float(trajectory.attrs.get("wall_time_s", math.nan)),
    }


# -- Bayesian optimisation directly on the DEM ----------------------------------------------------------
def bayesopt_on_dem(
    measured: MeasuredColumn,
    case_fields: dict,
    bounds: Sequence[Sequence[float]],
    runout: RunoutMethod,
    budget: int = BO_MAX_RUNS,
    n_initial: int = 6,
    seed: int = 0,
    names: Sequence[str] = ("friction", "restitution"),
    dem_config: dict | None = None,
    progress: Callable[[float], None] | None = None,
) -> tuple[OptimisationHistory, Trajectory, float]:
    """GP expected-improvement BO where every objective call is a DEM run of the measured column.
    progress: callable(fraction of the budget run), e.g. dem.progress.progress_logger.

    Returns (OptimisationHistory, best trajectory, seconds spent). The best run's objective is a
    validated value by construction: it is a DEM run with the same settings as the validation runs.
    A DEM run that fails (dem.engines.FAILURES) is recorded in the history's `failed` list with its
    reason and the optimisation goes on; none ran: calibration.optimise.OptimisationError.
    """
    if not 2 <= budget <= BO_MAX_RUNS:
        raise ComparisonError(f"bayesopt budget {budget}: must be between 2 and {BO_MAX_RUNS} DEM runs")
    best = {"value": math.inf, "trajectory": None, "runs": 0}

    def dem_objective(params):
        try:
            trajectory = dem_run(
                measured, dict(zip(names, params)), case_fields, name="bayesopt", dem_config=dem_config
            )
            value = objective(trajectory, measured, runout)
        except FAILURES as exc:
            raise PointFailed(failure_reason(exc)) from exc
        finally:
            best["runs"] += 1
            if progress is not None:
                progress(best["runs"] / budget)
        if value < best["value"]:
            best.update(value=value, trajectory=trajectory)
        return value

    start = time.perf_counter()
    settings = BOSettings(budget=budget, n_initial=min(n_initial, budget), seed=seed)
    result = bayesian_optimisation(one_at_a_time(dem_objective), bounds, list(names), settings)
    return result.history, best["trajectory"], time.perf_counter() - start


def write_bayesopt(history: OptimisationHistory, seconds: float, path: str | os.PathLike, runout: RunoutMethod) -> None:
    """bayesopt.json: the history's to_dict (the failed runs with their reasons under "failed"), the
    number of DEM runs (failed ones included), the seconds spent and the runout method."""
    write_text(
        path,
        json.dumps(
            {**history.to_dict(), "dem_runs": history.n_calls, "seconds": seconds, "runout": runout.to_config()},
            indent=1,
        )
        + "\n",
    )


def plot_bayesopt(history: dict, path: str | os.PathLike, title: str = "") -> None:
    """The BO runs in parameter space (coloured by objective, numbered in order) and the best-so-far
    objective against the number of DEM runs."""
    from dem.plots import plt, save_figure

    params = np.array(history["params"])
    values = np.array(history["values"])
    fig, (ax_p, ax_v) = plt.subplots(1, 2, figsize=(10, 4.2))
    dots = ax_p.scatter(params[:, 0], params[:, 1], c=values, cmap="viridis", s=40, edgecolors="k")
    for k, (x, y) in enumerate(params[:, :2]):
        ax_p.annotate(str(k + 1), (x, y), fontsize=6, xytext=(3, 3), textcoords="offset points")
    best = np.array(history["best_params"])  # drawn in the plane of the first two parameters (mu, e)
    ax_p.plot(best[0], best[1], "r*", ms=15, mec="w", label=f"best ({', '.join(f'{v:.3f}' for v in best)})")
    fig.colorbar(dots, ax=ax_p, label="objective (runout MSE), DEM")
    ax_p.set(xlabel=history["names"][0], ylabel=history["names"][1], title="DEM runs chosen by BO")
    ax_p.legend(fontsize=7)
    runs = np.arange(1, len(values) + 1)
    ax_v.plot(runs, values, "o", ms=4, label="each run")
    ax_v.plot(runs, np.minimum.accumulate(values), "-", label="best so far")
    ax_v.set(xlabel="DEM runs", ylabel="objective (runout MSE)", yscale="log", title=title or "Bayesian optimisation")
    ax_v.grid(alpha=0.3)
    ax_v.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


# -- the comparison table ----------------------------------------------------------------------------------
@dataclass
class Route:
    """One row of the comparison: a calibration route (or one stage of it)."""

    method: str  # "GNS inverse design", "DoE (quadratic)", "BO on DEM", "start point"
    stage: str  # "offline", "online", "total"
    dem_runs: int  # DEM runs this stage needed
    wall_s: float  # summed job wall time of this stage (s)
    task: str  # what the stage does
    validated_mse: float | None = None  # objective of the DEM run at the route's optimum
    friction: float | None = None
    restitution: float | None = None


def write_table(routes: list[Route], path: str | os.PathLike) -> None:
    """comparison.csv: one row per route (the fields of Route)."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(asdict(routes[0])))
            writer.writeheader()
            writer.writerows(asdict(r) for r in routes)


def read_table(path: str | os.PathLike) -> list[Route]:
    """The routes of a comparison.csv written by write_table."""

    def number(text, kind=float):
        return None if text in ("", "None") else kind(float(text))

    with open(path, newline="") as handle:
        return [
            Route(
                method=r["method"],
                stage=r["stage"],
                dem_runs=number(r["dem_runs"], int),
                wall_s=number(r["wall_s"]),
                task=r["task"],
                validated_mse=number(r["validated_mse"]),
                friction=number(r["friction"]),
                restitution=number(r["restitution"]),
            )
            for r in csv.DictReader(handle)
        ]


def markdown_table(routes: list[Route]) -> str:
    lines = [
        "| method (stage) | DEM runs | task | wall time | validated objective | mu | e |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in routes:
        mse = "" if r.validated_mse is None else f"**{r.validated_mse:.3f}**"
        mu = "" if r.friction is None else f"{r.friction:.3f}"
        e = "" if r.restitution is None else f"{r.restitution:.3f}"
        lines.append(
            f"| {r.method} ({r.stage}) | {r.dem_runs} | {r.task} | {_duration(r.wall_s)} | {mse} | {mu} | {e} |"
        )
    return "\n".join(lines)


def _duration(seconds: float) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "n/a"
    return f"{seconds:.1f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def route_totals(routes: list[Route]) -> dict:
    """{method: {"dem_runs", "wall_s", "validated_mse"}} summed over each method's stages."""
    totals: dict = {}
    for r in routes:
        t = totals.setdefault(r.method, {"dem_runs": 0, "wall_s": 0.0, "online_s": 0.0, "validated_mse": None})
        t["dem_runs"] += r.dem_runs
        t["wall_s"] += r.wall_s if math.isfinite(r.wall_s) else 0.0
        if r.stage != "offline":
            t["online_s"] += r.wall_s if math.isfinite(r.wall_s) else 0.0
        if r.validated_mse is not None:
            t["validated_mse"] = r.validated_mse
    return totals


def plot_comparison(routes: list[Route], path: str | os.PathLike, title: str = "") -> None:
    """Validated objective of each route against its DEM runs and its wall time (total and online)."""
    from dem.plots import plt, save_figure

    totals = {m: t for m, t in route_totals(routes).items() if t["validated_mse"] is not None}
    fig, (ax_runs, ax_time) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, (method, t) in enumerate(totals.items()):
        colour = plt.get_cmap("tab10")(k % 10)
        ax_runs.plot(t["dem_runs"], t["validated_mse"], "o", ms=9, color=colour, label=method)
        ax_time.plot(t["wall_s"] / 60, t["validated_mse"], "o", ms=9, color=colour, label=f"{method}: total")
        if t["online_s"] < t["wall_s"]:
            ax_time.plot(
                t["online_s"] / 60,
                t["validated_mse"],
                "s",
                ms=7,
                mfc="none",
                color=colour,
                label=f"{method}: online only",
            )
    ax_runs.set(
        xlabel="DEM runs",
        ylabel="validated objective (runout MSE, DEM at the optimum)",
        title="accuracy against DEM runs",
    )
    ax_time.set(
        xlabel="wall time (min, summed over jobs)",
        ylabel="validated objective",
        xscale="log",
        title="accuracy against time",
    )
    for ax in (ax_runs, ax_time):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def comparison_routes(
    measured: MeasuredColumn,
    inverse: dict,
    gns_validation: Trajectory,
    start: Trajectory,
    times: dict,
    runout: RunoutMethod,
    doe: dict | None = None,
    bayesopt: dict | None = None,
) -> list[Route]:
    """The comparison rows of one measured column.

    inverse: the inverse design's result (inverse.json); gns_validation: DEM run at its optimum;
    start: DEM run at the paper's start point (the uncalibrated guess). times (s, from the benchmark
    files): "start", "gns_dataset" (seconds, DEM runs), "gns_training", "gns_validation", and when
    given "doe" (seconds, DEM runs of the design and its analysis), "doe_validation" {model: s},
    "bayesopt". doe: {model: Trajectory} of the DoE validation runs, or None; bayesopt: the
    bayesopt.json dict, or None. runout: how every validated L* is read.
    """
    first = validation_summary(start, measured, runout)
    routes = [
        Route(
            "start point",
            "total",
            1,
            times.get("start", math.nan),
            "one DEM run at the paper's start",
            first["mse"],
            first["friction"],
            first["restitution"],
        )
    ]
    dataset_s, dataset_runs = times["gns_dataset"]
    gns = validation_summary(gns_validation, measured, runout)
    routes += [
        Route(
            "GNS inverse design",
            "offline",
            dataset_runs,
            dataset_s + times["gns_training"],
            "DEM dataset + GNS training",
        ),
        Route(
            "GNS inverse design",
            "online",
            1,
            inverse["seconds"]["online"] + times["gns_validation"],
            f"L-BFGS-B ({inverse['gradient']}, {len(inverse['starts'])} starts) + 1 DEM validation",
            gns["mse"],
            gns["friction"],
            gns["restitution"],
        ),
    ]
    for model, trajectory in (doe or {}).items():
        doe_s, doe_runs = times["doe"]
        summary = validation_summary(trajectory, measured, runout)
        routes.append(
            Route(
                f"DoE ({model})",
                "total",
                doe_runs + 1,
                doe_s + times["doe_validation"][model],
                "factorial DEM runs + regression + 1 DEM validation",
                summary["mse"],
                summary["friction"],
                summary["restitution"],
            )
        )
    if bayesopt:
        routes.append(
            Route(
                "BO on DEM",
                "total",
                bayesopt["dem_runs"],
                times.get("bayesopt", bayesopt["seconds"]),
                f"GP expected improvement on DEM runs (budget {bayesopt['dem_runs']})",
                bayesopt["best_value"],
                *bayesopt["best_params"][:2],
            )
        )
    return routes
