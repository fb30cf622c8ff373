"""The one Gaussian process of the calibration, built and fitted here for both of its users: the
emulator of DEM observables (calibration.emulator.GPEmulator) and Bayesian optimisation on DEM runs
(calibration.bayesopt).

The GP: constant x Matern-5/2 (one length scale per input) plus white noise, on inputs scaled to
the unit cube; its hyperparameters are fitted by scikit-learn (maximum marginal likelihood, from the
given starting values and within the given bounds).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from threadpoolctl import threadpool_limits

if TYPE_CHECKING:
    from sklearn.gaussian_process import GaussianProcessRegressor

SKLEARN_BOUNDS = (1e-5, 1e5)  # scikit-learn's default bounds of every hyperparameter


def fit_gp(
    u: np.ndarray,
    y: np.ndarray,
    amplitude: float,
    length_scale: float | np.ndarray,
    noise: float,
    *,
    amplitude_bounds: Sequence[float] = SKLEARN_BOUNDS,
    length_bounds: Sequence[float] = SKLEARN_BOUNDS,
    noise_bounds: Sequence[float] = SKLEARN_BOUNDS,
    alpha: float = 1e-10,
    n_restarts: int = 0,
    seed: int = 0,
) -> GaussianProcessRegressor:
    """A GP fitted to y [n] at unit-cube points u [n, p] (y scaled by the caller: no normalisation).

    amplitude (variance of y), length_scale (scalar or [p], in unit-cube lengths), noise (white-noise
    variance of y): where the hyperparameter search starts; *_bounds: (low, high) of each. alpha:
    jitter added to the kernel's diagonal. n_restarts: further searches from random starts (seeded
    by `seed`). Hyperparameters at their bounds are accepted without a warning.
    """
    # imported here: ~1 s of start-up that the many jobs importing this module without fitting skip
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    kernel = ConstantKernel(amplitude, amplitude_bounds) * Matern(length_scale, length_bounds, nu=2.5) + WhiteKernel(
        noise, noise_bounds
    )
    gp = GaussianProcessRegressor(
        kernel, alpha=alpha, normalize_y=False, n_restarts_optimizer=n_restarts, random_state=seed
    )
    # matrices of a few dozen rows: BLAS threads only fight over the shared cores
    with warnings.catch_warnings(), threadpool_limits(1):
        warnings.simplefilter("ignore", ConvergenceWarning)
        gp.fit(u, y)
    return gp
