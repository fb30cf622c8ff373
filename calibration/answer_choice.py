"""Which validated route is the answer (calibration/calibrated.py validates them): the routes not
told apart from the best by their paired packing scatter (`contenders`) run on more packings
(`runoff`) and the lowest there is the answer (`choose_answer`); `gns_versus_doe` holds the GNS
route against each DoE route of the model, the paper's claim. Routes are Validation dicts
(calibration.calibrated.Validation.to_dict()) with their `key` and `route` label, all scored on the
same validation packings, the first ones of every route shared.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from calibration.calibrated import mse_jackknife, validate
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from dem.runout import RunoutMethod

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


def not_told_apart(difference: float, se: float | None, z: float = 2.0) -> bool:
    """A route's MSE minus the best's (paired, mse_jackknife) within z standard errors; with no error
    (fewer than 3 packings both ran) every finite difference is."""
    return math.isfinite(difference) and (se is None or difference <= z * se)


def contenders(routes: Sequence[dict], measured: ArrayLike, best: dict, z: float = 2.0) -> list[dict]:
    """The routes (Validation dicts on the same packings) not told apart from `best`: their MSE minus
    best's, paired packing by packing (mse_jackknife), within z standard errors; with no error (fewer
    than 3 packings both ran) every route that ran is one; a route with no packing in common with
    best's is none. `best` comes first."""
    close = [best]
    for route in routes:
        if route is best:
            continue
        if not_told_apart(*mse_jackknife(route["curves"], measured, best["curves"]), z):
            close.append(route)
    return close


def runoff(
    routes: Sequence[dict],
    model: Model,
    column: MeasuredColumn,
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_packings: int,
    progress: Callable[[float], None] | None = None,
) -> list[dict]:
    """Each route (a Validation dict of `model` with its parameters and curves on the first packings)
    run on the validation packings after its own up to n_packings in all and scored on all of them:
    [{key, route, parameters, seeds, curves, failed, mse, mse_se, mse_each, shared_packings}] in the
    order given (failed: {seed: reason}; curves None where a run failed). progress: callable(fraction
    done)."""
    out = []
    for j, route in enumerate(routes):
        shared = len(route["seeds"])
        theta = [route["parameters"][name] for name in model.parameter_names]
        within = None if progress is None else (lambda f, j=j: progress((j + f) / len(routes)))
        more = validate(
            route["route"], model, column, theta, settings, runout, dem_config, n_packings - shared,
            progress=within, first_packing=shared,
        )  # fmt: skip
        curves = list(route["curves"]) + more.curves
        mse, se = mse_jackknife(curves, column.runout)
        failed = {int(seed): why for seed, why in route["failed"].items()} | more.failed
        out.append(
            {
                "key": route.get("key"),
                "route": route["route"],
                "parameters": route["parameters"],
                "seeds": list(route["seeds"]) + more.seeds,
                "curves": curves,
                "failed": failed,
                "mse": mse,
                "mse_se": se,
                "mse_each": list(route["mse_each"]) + more.mse_each,
                "shared_packings": shared,
            }
        )
    return out


def lowest(routes: Sequence[dict]) -> dict:
    """The route of the lowest finite MSE (a route whose every run failed scores NaN: never the lowest)."""
    return min(routes, key=lambda r: r["mse"] if math.isfinite(r["mse"]) else math.inf)


def choose_answer(
    routes: Sequence[dict],
    model: Model,
    column: MeasuredColumn,
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem_config: dict | None,
    n_packings: int,
    answer_packings: int,
    progress: Callable[[float], None] | None = None,
) -> tuple[dict, list[dict]]:
    """(the answer, the runoff's entries) of the validated routes of `model`, each on n_packings
    packings: the lowest of a few noisy scores flatters itself, so the routes within 2 SE of the
    lowest (`contenders`) run on answer_packings packings in all (`runoff`) and the lowest there is
    the answer (its validation record, from `routes`); without a runoff (answer_packings not above
    n_packings, or one contender) the lowest validated route and []. progress: callable(fraction done)."""
    best = lowest(routes)
    close = contenders(routes, column.runout, best)
    if answer_packings <= n_packings or len(close) <= 1:
        return best, []
    scored = runoff(close, model, column, settings, runout, dem_config, answer_packings, progress)
    winner = lowest(scored)
    return next(r for r in routes if r["key"] == winner["key"]), scored


def gns_versus_doe(routes: Sequence[dict], scored: Sequence[dict], measured: ArrayLike) -> list[dict]:
    """The model's GNS route (key model-inverse) against each of its DoE routes (keys model-doe*),
    the paper's claim that the GNS route does no worse at no more DEM runs: [{doe_key, doe_route,
    mse_difference (GNS minus DoE, paired packing by packing), se (jackknife; None under 3
    packings), packings, gns_dem_runs, gns_own_dem_runs, doe_dem_runs}], on the runoff's packings
    (`scored`) where both ran there, else on the validation's; [] without a GNS route. measured [K]:
    the measured L*."""
    gns = next((r for r in routes if r["key"] == "model-inverse"), None)
    if gns is None:
        return []
    runoff_curves = {r["key"]: r["curves"] for r in scored}
    out = []
    for doe in [r for r in routes if r["key"].startswith("model-doe")]:
        mine, theirs = gns["curves"], doe["curves"]
        if gns["key"] in runoff_curves and doe["key"] in runoff_curves:
            mine, theirs = runoff_curves[gns["key"]], runoff_curves[doe["key"]]
        difference, se = mse_jackknife(mine, measured, theirs)
        out.append(
            {
                "doe_key": doe["key"],
                "doe_route": doe["route"],
                "mse_difference": difference,
                "se": se,
                "packings": len(mine),
                "gns_dem_runs": gns["dem_runs"],
                "gns_own_dem_runs": gns.get("own_dem_runs"),  # without the base GNS's (shared with the paper's route)
                "doe_dem_runs": doe["dem_runs"],
            }
        )
    return out
