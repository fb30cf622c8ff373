"""A model calibrated on its Gaussian-process emulator, and scored by information criteria.

Noise is Gaussian of known std sigma [q] (calibration/residuals.py's NoiseModel), so -2 log L =
chi^2 + const with chi^2 = sum((measured - model)^2 / sigma^2), and:

- `aic`, `bic`: Akaike and Bayesian information criteria from chi^2 (lower is better);
- `p_value`: P(chi^2 >= observed) with n - p degrees of freedom;
- `fit_emulated`: the parameters minimising chi^2 over the emulator's box;
- `predictive_chi2`: the held-out chi^2 of a prediction from a fit without the held-out values,
  carrying that fit's parameter uncertainty (`box_bounded_covariance`); the emulator's and the
  DEM's held-out scores (calibration/dem_scoring.py) both use it;
- `score_model` -> `ModelScore`: a model fitted on all data and without each held-out fold, with
  its Laplace posterior (and each fold's); `EmulatorFit` and `FinalFit` are what the diagnosis
  reports of it (JSON).

Scoring in the DEM itself, at the optima found here, is calibration/dem_scoring.py's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.stats import chi2 as chi2_distribution
from scipy.stats import qmc
from threadpoolctl import threadpool_limits

from calibration.emulator import GPEmulator
from calibration.model import Model
from calibration.objective import runout_mse
from calibration.observables import Observables
from calibration.residuals import Fold
from calibration.uncertainty import LaplacePosterior, laplace_posterior


# -- information criteria ------------------------------------------------------------------------------
def aic(chi2: float, n_parameters: int) -> float:
    """Akaike information criterion under Gaussian noise of known sigma: -2 log L = chi^2 + const."""
    return chi2 + 2 * n_parameters


def bic(chi2: float, n_parameters: int, n_data: int) -> float:
    """Bayesian information criterion, chi^2 + p ln n (same noise model as `aic`)."""
    return chi2 + n_parameters * math.log(n_data)


def p_value(chi2: float, n_parameters: int, n_data: int) -> float:
    """P(chi^2 >= observed) with n - p degrees of freedom, if the model and the noise were right."""
    return float(chi2_distribution.sf(chi2, max(n_data - n_parameters, 1)))


# -- the held-out score: a predictive check ---------------------------------------------------------------
def box_bounded_covariance(covariance: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """[p, p] a Laplace covariance `covariance` [p, p] (parameter units squared) bounded by the box
    bounds [p, 2]: (Sigma^-1 + diag(12 / width^2))^-1, width = high - low.

    This adds to the fit's information a Gaussian prior of the box's own spread (a uniform
    distribution over width has variance width^2 / 12): a well-determined parameter keeps its
    Laplace variance (its information dwarfs the prior's), a direction the data cannot see (the
    posterior's "not identifiable", variance ~1e12 from the ridge) comes out with the box's variance
    instead of an infinite one, and no marginal variance exceeds width^2 / 12. Computed in the
    unit-scaled parameters, Sigma_u = Sigma / (width width^T) = V diag(lambda) V^T, as
    V diag(lambda / (1 + 12 lambda)) V^T: stable for lambda from 0 to 1e30.
    """
    covariance = np.asarray(covariance, float)
    width = np.asarray(bounds, float)[:, 1] - np.asarray(bounds, float)[:, 0]
    unit = covariance / np.outer(width, width)
    eigenvalues, vectors = np.linalg.eigh(0.5 * (unit + unit.T))
    eigenvalues = np.maximum(eigenvalues, 0.0)
    bounded = (vectors * (eigenvalues / (1.0 + 12.0 * eigenvalues))) @ vectors.T
    return bounded * np.outer(width, width)


def predictive_chi2(
    residual: np.ndarray, sigma: np.ndarray, jacobian: np.ndarray | None = None, covariance: np.ndarray | None = None
) -> float:
    """Held-out chi^2 of a prediction that carries its fit's parameter uncertainty (dimensionless):

        chi^2 = r^T (C_noise + J Sigma J^T)^-1 r,   C_noise = diag(sigma^2)

    residual r [h]: predicted - measured of the h held-out values (L* or m, per value); sigma [h]:
    their noise std (same units); jacobian J [h, p]: d(predicted value)/d(parameter) at the fold
    fit's optimum (value units per parameter unit); covariance Sigma [p, p]: the fold fit's
    posterior covariance (parameter units squared; `box_bounded_covariance`). The fold's fit
    predicts the held-out values as a Gaussian of mean `predicted` and covariance J Sigma J^T; the
    measurement adds its noise. A parameter the fold's data do not constrain widens the prediction
    instead of betting on one arbitrary value, so a miss along the direction it moves the
    prediction costs little and a miss it cannot explain costs as much as before. Sigma = 0 (or
    None): the plug-in sum((r / sigma)^2); never above it (C_noise + J Sigma J^T >= C_noise).
    Solved whitened, (I + J' Sigma J'^T) with J' = J / sigma, by Cholesky.
    """
    whitened = np.asarray(residual, float) / np.asarray(sigma, float)
    if jacobian is None or covariance is None or whitened.size == 0:
        return float(whitened @ whitened)
    scaled = np.asarray(jacobian, float).reshape(whitened.size, -1) / np.asarray(sigma, float)[:, None]
    spread = scaled @ np.asarray(covariance, float) @ scaled.T
    factor = np.linalg.cholesky(np.eye(whitened.size) + 0.5 * (spread + spread.T))
    solved = np.linalg.solve(factor, whitened)
    return float(solved @ solved)


# -- fitting on the emulator ------------------------------------------------------------------------------
def fit_emulated(
    emulator: GPEmulator,
    target: np.ndarray,
    sigma: np.ndarray,
    mask: np.ndarray | None = None,
    seed: int = 0,
    n_sweep: int = 1024,
) -> tuple[np.ndarray, float]:
    """(theta [p], chi^2) minimising chi^2 over the emulator's box on the outputs in `mask` [q] bool.

    target [q]: measured values; sigma [q]: their noise std (same units, L* or m). A Sobol sweep of
    the box's unit cube (`n_sweep` points), then L-BFGS-B from the three best points: the emulator is
    cheap, and a sweep does not get stuck where a mechanism switches on.
    """
    mask = np.ones(len(target), bool) if mask is None else np.asarray(mask, bool)
    weight = 1.0 / sigma[mask]

    def chi2(unit):
        return np.sum(((emulator.predict_unit(unit)[:, mask] - target[mask]) * weight) ** 2, axis=1)

    sweep = qmc.Sobol(d=len(emulator.bounds), seed=seed).random(n_sweep)
    values = chi2(sweep)
    best_unit, best_value = sweep[int(np.argmin(values))], float(values.min())
    with threadpool_limits(1):  # tiny problems: BLAS threads only fight over the shared cores
        for start in sweep[np.argsort(values)[:3]]:
            result = minimize(lambda u: float(chi2(u)[0]), start, method="L-BFGS-B", bounds=[(0, 1)] * len(start))
            if result.fun < best_value:
                best_unit, best_value = np.clip(result.x, 0, 1), float(result.fun)
    return emulator.box.from_unit(best_unit)[0], best_value


# -- what is reported of a fit ------------------------------------------------------------------------------
@dataclass(frozen=True)
class EmulatorFit:
    """A model calibrated on its emulator, as the diagnosis reports it (the JSON "emulator" entry).

    Chi^2 values are against the noise std (dimensionless); MSEs are of the runout L* (L*^2).
    """

    parameters: dict[str, float]  # calibrated parameters by name (friction, restitution[, mechanism's])
    posterior: LaplacePosterior  # Laplace posterior around them, from the emulator's Jacobian
    chi2: float  # of the emulated observables at the optimum, over all n_data values
    n_data: int  # measured values q
    n_parameters: int  # p
    p_value: float  # P(chi^2 >= chi2) with n_data - n_parameters degrees of freedom
    aic: float
    bic: float
    fit_mse: float  # runout MSE (the objective) of the emulated runout at the optimum
    # sum over folds of the predictive chi^2 of the held-out values (`predictive_chi2`), each from a
    # fit without them, its parameter uncertainty included
    heldout_chi2: float
    heldout_mse: float  # runout MSE on the held-out runout points (NaN: none held out)
    heldout_parameters: list[dict[str, float]]  # [folds] parameters fitted without each fold
    emulator_loo_over_noise: float  # median over outputs of the emulator's leave-one-out RMSE / noise std
    mechanism_z_off: float | None  # |parameter - off| / posterior std of an extension's mechanism; None: base

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        out = {name: getattr(self, name) for name in self.__dataclass_fields__}
        out["posterior"] = self.posterior.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EmulatorFit:
        """Inverse of `to_dict` (as read back from JSON)."""
        return cls(**{**data, "posterior": LaplacePosterior.from_dict(data["posterior"])})


@dataclass(frozen=True)
class FinalFit:
    """The emulator's last word on a model, after the DEM runs joined it (the JSON "emulator_final")."""

    parameters: dict[str, float]  # calibrated parameters by name
    chi2: float  # of the emulated observables against the noise
    bic: float
    heldout_chi2: float  # sum over folds, each from a fit without it

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FinalFit:
        """Inverse of `to_dict`."""
        return cls(**data)


@dataclass
class ModelScore:
    """A model calibrated on its emulator, and how well it does there."""

    model: str
    parameter_names: list[str]
    theta: np.ndarray  # [p] calibrated parameters
    predicted: np.ndarray  # [q] emulated observables at theta
    chi2: float
    n_data: int
    n_parameters: int
    fold_theta: list[np.ndarray]  # [folds][p] parameters fitted without each fold
    heldout_chi2: float
    heldout_mse: float  # runout MSE (the objective) on held-out runout points
    posterior: LaplacePosterior
    emulator_loo_over_noise: float  # median over outputs of the emulator's LOO RMSE / total noise
    mechanism_z_off: float | None = None  # |parameter - off| / std for an extension
    # [folds][q, p] emulator Jacobian of every output at each fold's parameters, and [folds][p, p]
    # each fold fit's Laplace covariance bounded by the box (`box_bounded_covariance`): what the
    # held-out chi^2 (`predictive_chi2`), here and in the DEM, widens the fold's prediction by
    fold_jacobian: list[np.ndarray] = field(default_factory=list)
    fold_covariance: list[np.ndarray] = field(default_factory=list)

    @property
    def bic(self) -> float:
        return bic(self.chi2, self.n_parameters, self.n_data)

    def parameters(self, theta: np.ndarray | None = None) -> dict[str, float]:
        """{name: value} of `theta` [p] (default: the calibrated parameters)."""
        return dict(zip(self.parameter_names, map(float, self.theta if theta is None else theta)))

    def summary(self, observables: Observables) -> EmulatorFit:
        """What the diagnosis reports of this fit; `observables` tell the runout outputs (for the MSE)."""
        runout = observables.kind == "runout"
        return EmulatorFit(
            parameters=self.parameters(),
            posterior=self.posterior,
            chi2=self.chi2,
            n_data=self.n_data,
            n_parameters=self.n_parameters,
            p_value=p_value(self.chi2, self.n_parameters, self.n_data),
            aic=aic(self.chi2, self.n_parameters),
            bic=self.bic,
            fit_mse=runout_mse(self.predicted[runout], observables.measured[runout]),
            heldout_chi2=self.heldout_chi2,
            heldout_mse=self.heldout_mse,
            heldout_parameters=[self.parameters(t) for t in self.fold_theta],
            emulator_loo_over_noise=self.emulator_loo_over_noise,
            mechanism_z_off=self.mechanism_z_off,
        )

    def final(self) -> FinalFit:
        """The short report of a fit: parameters, chi^2, BIC and held-out chi^2."""
        return FinalFit(self.parameters(), self.chi2, self.bic, self.heldout_chi2)


def score_model(
    model: Model,
    emulator: GPEmulator,
    observables: Observables,
    sigma: np.ndarray,
    folds: list[Fold],
    seed: int = 0,
    n_data: int | None = None,
) -> ModelScore:
    """Calibrate `model` on its emulator on all data and without each fold; its Laplace posterior.

    sigma [q]: the noise std of every measured value (calibration/residuals.py's NoiseModel.total);
    n_data: independent measured values (NoiseModel.n_effective; None: every output counts one).
    """
    target = observables.measured
    bounds = model.bounds
    theta, chi2 = fit_emulated(emulator, target, sigma, seed=seed)
    predicted = emulator.predict(theta)[0]
    heldout_chi2, squared, fold_theta, fold_jacobian, fold_covariance = 0.0, [], [], [], []
    for fold in folds:
        fit_k = ~fold.held
        theta_k, _ = fit_emulated(emulator, target, sigma, mask=fit_k, seed=seed + 1, n_sweep=512)
        prediction = emulator.predict(theta_k)[0]
        jacobian_k = emulator_jacobian(model, emulator, theta_k)
        posterior_k = laplace_posterior(
            list(model.parameter_names),
            theta_k,
            jacobian_k[fit_k],
            (prediction - target)[fit_k],
            bounds.tolist(),
            sigma=sigma[fit_k],
        )
        covariance_k = box_bounded_covariance(posterior_k.covariance, bounds)
        held = fold.held
        heldout_chi2 += predictive_chi2(prediction[held] - target[held], sigma[held], jacobian_k[held], covariance_k)
        runout = fold.held & (observables.kind == "runout")
        squared += list((prediction[runout] - target[runout]) ** 2)
        fold_theta.append(theta_k)
        fold_jacobian.append(jacobian_k)
        fold_covariance.append(covariance_k)
    posterior = laplace_posterior(
        list(model.parameter_names),
        theta,
        emulator_jacobian(model, emulator, theta),
        predicted - target,
        bounds.tolist(),
        sigma=sigma,
    )
    z_off = None
    if model.mechanism is not None:
        off = model.mechanism.off_value(theta[0], theta[1])
        std = posterior.parameters[-1].std
        z_off = float(abs(theta[-1] - off) / std) if std > 0 else math.inf
    return ModelScore(
        model.name,
        list(model.parameter_names),
        theta,
        predicted,
        float(chi2),
        observables.size if n_data is None else n_data,
        model.n_parameters,
        fold_theta,
        heldout_chi2,
        float(np.mean(squared)) if squared else math.nan,
        posterior,
        float(np.median(emulator.loo_rmse() / sigma)),
        z_off,
        fold_jacobian,
        fold_covariance,
    )


def emulator_jacobian(model: Model, emulator: GPEmulator, theta: np.ndarray) -> np.ndarray:
    """[q, p] d(emulated observable)/d(parameter) at theta [p]: central differences of 2% of the
    box's unit cube, kept inside it (one-sided at a bound)."""
    unit = model.box.to_unit(theta)[0]
    jacobian = []
    for j in range(model.n_parameters):
        up, down = unit.copy(), unit.copy()
        up[j], down[j] = min(unit[j] + 0.02, 1.0), max(unit[j] - 0.02, 0.0)
        theta_up, theta_down = model.box.from_unit(up)[0], model.box.from_unit(down)[0]
        jacobian.append(
            (emulator.predict(theta_up)[0] - emulator.predict(theta_down)[0]) / (theta_up[j] - theta_down[j])
        )
    return np.stack(jacobian, axis=1)
