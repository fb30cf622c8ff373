"""A model scored by DEM runs at its emulator optima, instead of by its emulator.

The emulator (calibration/scoring.py) is cheap but not exact: its error near an optimum can exceed
the noise. So the diagnosis runs the DEM at a model's calibrated parameters and at each held-out
fold's, on a few packings (`dem_runs` -> `DEMRuns`), and scores the model by those runs
(`dem_evaluate` -> `DEMScore`): chi^2, AIC, BIC, p-value, the runout objective, and held-out chi^2.
The held-out chi^2 is calibration/scoring.py's `predictive_chi2`, the one the emulator's score uses:
the DEM runs at a fold's parameters against the held-out data, with the noise and the fold fit's
parameter uncertainty (its box-bounded Laplace covariance, propagated by the emulator's Jacobian).

A run that fails (dem.engines.FAILURES) is recorded with its packing and reason (`failed_runs`)
and left out: the means are over the runs that ran, never over a failed one. When every packing
of the fit or of a fold fails, the model cannot be scored: a DiagnosisError with the reasons.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.design_runs import DEMRunner
from calibration.model import Model
from calibration.objective import runout_mse
from calibration.observables import Observables
from calibration.residuals import DiagnosisError, Fold, NoiseModel
from calibration.scoring import ModelScore, aic, bic, p_value, predictive_chi2
from dem.engines import FAILURES, failure_reason
from dem.runout import RunoutMethod
from dem.trajectory import Trajectory

log = logging.getLogger(__name__)

# A runout curve as drawn: [t/t* list, L* list] (every other frame of a run).
Curve = list[list[float]]


@dataclass(frozen=True)
class DEMRuns:
    """DEM runs of a model at its emulator optima, R packings each; the arrays hold the runs that
    ran (R' <= R rows), `failed` the others."""

    model: Model
    theta: np.ndarray  # [p] calibrated parameters
    fit: np.ndarray  # [R', q] observables of the runs at theta that ran
    fold_theta: list[np.ndarray]  # [folds][p] parameters fitted without each fold
    folds: list[np.ndarray]  # [folds][R', q] observables of the runs at each fold's parameters that ran
    packings: list[int]  # [R'] indices into the simulation's packing seeds of the rows of fit
    curves: list[list[Curve]]  # [R'][columns] runout curves of the fit runs (for the figure)
    seconds: float  # wall time of all these runs
    fold_packings: list[list[int]]  # [folds][R'] packings of the rows of folds
    failed: list[dict]  # the runs that failed: each {held_out ("" for the fit), parameters, packing, reason}
    # [folds][q, p] and [folds][p, p]: the emulator's Jacobian at each fold's parameters and the fold
    # fit's box-bounded covariance (ModelScore's); None: no parameter uncertainty (plug-in held-out chi^2)
    fold_jacobian: list[np.ndarray] | None = None
    fold_covariance: list[np.ndarray] | None = None


@dataclass(frozen=True)
class HeldOutFold:
    """One held-out fold in DEM runs: the held-out values predicted from a fit without them."""

    held_out: str  # what was held out, in words (calibration/residuals.py's Fold.description)
    # predictive chi^2 of the held-out values (calibration/scoring.py's `predictive_chi2`): against
    # the noise and the fold fit's parameter uncertainty
    chi2: float
    parameters: dict[str, float]  # the parameters fitted without them
    plugin_chi2: float | None = None  # against the noise alone, at the fold's parameters (None: not recorded)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> HeldOutFold:
        """Inverse of `to_dict`."""
        return cls(**data)


@dataclass(frozen=True, eq=False)
class DEMScore:
    """A model scored by its DEM runs (the JSON "dem" entry of a model's evidence).

    Chi^2 values are against the noise std (measurement + packing scatter of the measured
    realisation + that of a mean of R runs; dimensionless); MSEs are of the runout L* (L*^2).
    """

    parameters: dict[str, float]  # the calibrated parameters run
    packings: list[int]  # [R] indices into the simulation's packing seeds of the fit runs that ran
    chi2: float  # of the mean observables of the R runs, over all n_data values
    n_data: int  # measured values q
    n_parameters: int  # p
    p_value: float  # P(chi^2 >= chi2) with n_data - n_parameters degrees of freedom
    aic: float
    bic: float
    objective: float  # runout MSE against the measurement, mean over the R runs
    objective_per_packing: list[float]  # [R] runout MSE of each run
    heldout_chi2: float  # sum over folds of the predictive chi^2 of the held-out values (HeldOutFold.chi2)
    n_heldout: int  # held-out values, all folds together
    heldout_mse: float  # runout MSE on the held-out runout points (NaN: none held out)
    heldout_folds: list[HeldOutFold]  # [folds]
    observed_mean: np.ndarray  # [q] mean observables of the R runs at the calibrated parameters
    sigma: np.ndarray  # [q] noise std the chi^2 values use (L* or m)
    curves: list[list[Curve]]  # [R][columns] runout curves of the runs (for the figure)
    seconds: float  # wall time of the runs
    # runs that failed, left out of every number above: each {held_out ("" for the fit), parameters,
    # packing, reason}
    failed_runs: list[dict] = field(default_factory=list)
    # sum over folds of the plug-in chi^2 (noise alone, HeldOutFold.plugin_chi2); None: not recorded
    heldout_plugin_chi2: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        out = {name: getattr(self, name) for name in self.__dataclass_fields__}
        out.update(
            heldout_folds=[f.to_dict() for f in self.heldout_folds],
            observed_mean=self.observed_mean.tolist(),
            sigma=self.sigma.tolist(),
        )
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DEMScore:
        """Inverse of `to_dict` (as read back from JSON)."""
        return cls(
            **{
                **data,
                "heldout_folds": [HeldOutFold.from_dict(f) for f in data["heldout_folds"]],
                "observed_mean": np.asarray(data["observed_mean"], float),
                "sigma": np.asarray(data["sigma"], float),
            }
        )


def dem_runs(
    runner: DEMRunner,
    model: Model,
    score: ModelScore,
    folds: list[Fold],
    n_packings: int,
    first_packing: int = 0,
) -> DEMRuns:
    """DEM runs of `model` at the emulator's optima: at the calibrated parameters and at each
    fold's (every column, so that the runs can also refine the emulator), on `n_packings` packings
    from `first_packing` on (cyclically through the runner's packing seeds). A run that fails is
    recorded and left out; DiagnosisError when no packing of the fit or of a fold ran."""
    n_pool = len(runner.settings.packing_seeds)
    packings = [(first_packing + r) % n_pool for r in range(n_packings)]
    started = time.perf_counter()
    failed: list[dict] = []

    def run_all(theta: np.ndarray, held_out: str) -> tuple[list[np.ndarray], list[int], list[list[Curve]]]:
        observed, ran, curves = [], [], []
        for k in packings:
            try:
                trajectories = runner.trajectories(model, theta, k)
                observables = runner.observables
                one = observables.from_trajectories(trajectories)
                curve = (
                    [_thin_curve(tr, observables.reading(c)) for tr, c in zip(trajectories, observables.columns)]
                    if not held_out
                    else []
                )
            except FAILURES as exc:  # recorded with its packing, never averaged in
                parameters = dict(zip(model.parameter_names, map(float, theta)))
                reason = failure_reason(exc)
                failed.append({"held_out": held_out, "parameters": parameters, "packing": k, "reason": reason})
                log.warning("DEM run of %s at %s on packing %d failed, left out: %s", model.name, parameters, k, reason)
                continue
            observed.append(one)
            ran.append(k)
            if not held_out:
                curves.append(curve)
        if not ran:
            where = f"without {held_out}" if held_out else "at its calibrated parameters"
            raise DiagnosisError(
                f"{model.name}: every DEM run {where} failed, so the model cannot be scored in DEM runs: "
                + "; ".join(f"packing {f['packing']}: {f['reason']}" for f in failed if f["held_out"] == held_out)
            )
        return observed, ran, curves

    fit, fit_packings, curves = run_all(score.theta, "")
    fold_runs, fold_packings = [], []
    for fold, theta_k in zip(folds, score.fold_theta):
        observed, ran, _ = run_all(theta_k, fold.description)
        fold_runs.append(np.array(observed))
        fold_packings.append(ran)
    return DEMRuns(
        model=model,
        theta=score.theta,
        fit=np.array(fit),
        fold_theta=score.fold_theta,
        folds=fold_runs,
        packings=fit_packings,
        curves=curves,
        seconds=time.perf_counter() - started,
        fold_packings=fold_packings,
        failed=failed,
        # a score without fold posteriors (a bare theta/fold_theta) is scored plug-in
        fold_jacobian=getattr(score, "fold_jacobian", None) or None,
        fold_covariance=getattr(score, "fold_covariance", None) or None,
    )


def noise_std(noise: NoiseModel, n_runs: int) -> np.ndarray:
    """[q] noise std of the mean of n_runs DEM runs against the data: measurement + packing scatter
    of the measured realisation + that of the mean of the runs."""
    return np.sqrt(noise.measurement**2 + noise.packing**2 * (1 + 1 / n_runs)) * noise.correlation


def dem_evaluate(runs: DEMRuns, observables: Observables, folds: list[Fold], noise: NoiseModel) -> DEMScore:
    """The model scored by its DEM runs (`dem_runs`) instead of its emulator.

    Fit: the mean observables of the runs at the calibrated parameters against the data give chi^2
    (noise: measurement + packing scatter of the measured realisation + that of a mean of R runs),
    AIC, BIC, p-value; the objective (runout MSE) is averaged over the runs. Held out: each fold's
    runs at the parameters fitted without it, on the held-out outputs only, scored by
    `predictive_chi2`: r^T (diag(sigma^2) + J Sigma J^T)^-1 r with r the mean of the fold's runs
    minus the data and sigma the noise of that mean, J [h, p] the emulator's Jacobian of the
    held-out outputs at the fold's parameters and Sigma [p, p] the fold fit's box-bounded Laplace
    covariance (`runs.fold_jacobian`, `runs.fold_covariance`; without them, Sigma = 0).
    """
    model = runs.model
    target = observables.measured
    runout = observables.kind == "runout"
    sigma = noise_std(noise, len(runs.fit))  # the runs that ran: a failed one is in no mean
    mean = runs.fit.mean(axis=0)
    chi2 = float(np.sum(((mean - target) / sigma) ** 2))
    heldout_chi2, plugin_chi2, squared, folds_out = 0.0, 0.0, [], []
    n_folds = len(runs.folds)
    jacobians = runs.fold_jacobian or [None] * n_folds
    covariances = runs.fold_covariance or [None] * n_folds
    for fold, theta_k, fold_runs, jacobian, covariance in zip(
        folds, runs.fold_theta, runs.folds, jacobians, covariances
    ):
        held = fold.held
        residual = fold_runs.mean(axis=0)[held] - target[held]
        fold_sigma = noise_std(noise, len(fold_runs))[held]
        fold_chi2 = predictive_chi2(residual, fold_sigma, None if jacobian is None else jacobian[held], covariance)
        fold_plugin = predictive_chi2(residual, fold_sigma)
        heldout_chi2 += fold_chi2
        plugin_chi2 += fold_plugin
        squared += list(residual[runout[held]] ** 2)
        folds_out.append(
            HeldOutFold(fold.description, fold_chi2, dict(zip(model.parameter_names, map(float, theta_k))), fold_plugin)
        )
    objective = [runout_mse(r[runout], target[runout]) for r in runs.fit]
    result = DEMScore(
        parameters=dict(zip(model.parameter_names, map(float, runs.theta))),
        packings=runs.packings,
        chi2=chi2,
        n_data=noise.n_effective,
        n_parameters=model.n_parameters,
        p_value=p_value(chi2, model.n_parameters, noise.n_effective),
        aic=aic(chi2, model.n_parameters),
        bic=bic(chi2, model.n_parameters, noise.n_effective),
        objective=float(np.mean(objective)),
        objective_per_packing=objective,
        heldout_chi2=heldout_chi2,
        n_heldout=int(sum(int(fold.held.sum()) for fold in folds)),
        heldout_mse=float(np.mean(squared)) if squared else math.nan,
        heldout_folds=folds_out,
        observed_mean=mean,
        sigma=sigma,
        curves=runs.curves,
        seconds=runs.seconds,
        failed_runs=runs.failed,
        heldout_plugin_chi2=plugin_chi2,
    )
    log.info(
        "DEM score of %s: chi2 %.1f, BIC %.1f, held-out chi2 %.1f (plug-in %.1f), objective %.4g",
        model.name,
        chi2,
        result.bic,
        heldout_chi2,
        plugin_chi2,
        result.objective,
    )
    return result


def _thin_curve(trajectory: Trajectory, runout: RunoutMethod) -> Curve:
    """[t/t* list, L* list] of a run's runout curve as the diagnosis reads it, every other frame (for the figure)."""
    t, runout = runout.curve(trajectory)
    return [t[::2].round(4).tolist(), runout[::2].round(4).tolist()]
