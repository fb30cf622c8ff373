"""The DoE route for a campaign of several columns (calibration/campaign.py): the face-centred CCD
over the model's parameters (doe/model_study.py's), every design point run on every column on the
same packing, and one quadratic response surface of the campaign objective (the weighted mean of
the columns' MSEs) per set of columns. Holding a column out refits the surface to the rest's
columns from the same runs, so it costs no DEM run.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from calibration.calibrated import CALIBRATION_SEED
from calibration.campaign import Campaign, CampaignOptimum, CampaignRunner
from doe.design import face_centred_ccd
from doe.model_study import SURFACE, model_factors
from doe.regression import RegressionError, SurfaceFit, analyse

MSE_PREFIX = "mse_"  # responses column of one column's runout MSE: mse_<column>
SECONDS_PREFIX = "seconds_"
FAILURE_PREFIX = "failure_"


def campaign_doe(
    runner: CampaignRunner,
    centre_replicates: int = 3,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
) -> pd.DataFrame:
    """The CCD's runs on every column of the campaign: the design table (doe.design columns; seed:
    the packing, CALIBRATION_SEED + seed but for the centre replicates) with, per column c,
    mse_<c> (NaN where its run failed), seconds_<c> and failure_<c> ("" where it ran)."""
    design = face_centred_ccd(model_factors(runner.model), centre_replicates, CALIBRATION_SEED + seed)
    names = list(runner.model.parameter_names)
    records = []
    for done, row in enumerate(design.itertuples(index=False), start=1):
        mse, seconds, failures = runner.run_all([float(getattr(row, n)) for n in names], int(row.seed))
        record = {"run_id": row.run_id}
        for column, m, s, f in zip(runner.campaign.column_names, mse, seconds, failures):
            record.update({MSE_PREFIX + column: m, SECONDS_PREFIX + column: s, FAILURE_PREFIX + column: f})
        records.append(record)
        if progress is not None:
            progress(done / len(design))
    return design.merge(pd.DataFrame(records), on="run_id")


def campaign_surface(
    responses: pd.DataFrame, runner: CampaignRunner, columns: Sequence[str]
) -> tuple[CampaignOptimum, SurfaceFit, pd.DataFrame]:
    """The quadratic surface of the campaign objective over `columns`, from campaign_doe's runs
    (a design point where one of them failed is left out): (its bounded optimum, the fit, the runs
    fitted with their objective in column `mse`)."""
    campaign = runner.campaign
    values = responses[[MSE_PREFIX + c for c in campaign.column_names]].to_numpy(float)
    runs = responses.assign(mse=[campaign.objective(row, columns) for row in values])
    runs = runs[np.isfinite(runs["mse"])]
    factors = model_factors(runner.model)
    try:
        fits, analysis = analyse(runs, factors, "mse", models=(SURFACE,))
    except RegressionError as exc:
        raise RegressionError(f"campaign {campaign.name} DoE on {list(columns)}: {exc}") from exc
    optimum = analysis["models"][SURFACE]["optimum"]
    parameters = {name: float(optimum["natural"][name]) for name in runner.model.parameter_names}
    return CampaignOptimum(list(columns), parameters, float(optimum["predicted"])), fits[SURFACE], runs


def column_costs(responses: pd.DataFrame, campaign: Campaign) -> tuple[int, float]:
    """(DEM runs, wall time (s)) of campaign_doe's runs of all columns."""
    seconds = responses[[SECONDS_PREFIX + c for c in campaign.column_names]].to_numpy(float)
    return int(seconds.size), float(seconds.sum())
