"""A Gaussian-process emulator of what DEM runs measure, over a model's parameter box.

Why an emulator: the diagnosis fits six models (the base model and five extensions), each several
times over (every held-out fold), and a builtin-DEM run of the test columns takes a second or more.
So each model gets a space-filling design of DEM runs once (a seeded Latin hypercube over its box,
`latin_hypercube`; the runs: `build_library` in calibration/design_runs.py), and every fit is done
on a cheap emulator of those runs (`GPEmulator`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import qmc

from calibration.gp import fit_gp
from calibration.observables import LibraryError


# -- the parameter box ----------------------------------------------------------------------------
@dataclass(frozen=True)
class ParameterBox:
    """Bounds [p, 2] of a model's parameters and the unit cube the design and the emulator use.

    A parameter with log_scale True maps to the cube through its logarithm (bounds must then be
    positive): for a parameter whose effect grows like its logarithm (basal friction), the design
    spreads evenly over that effect and the emulator sees a near-linear response.
    """

    bounds: np.ndarray
    log_scale: tuple

    def __post_init__(self):
        object.__setattr__(self, "bounds", np.asarray(self.bounds, float))
        if any(log and self.bounds[j, 0] <= 0 for j, log in enumerate(self.log_scale)):
            raise LibraryError(f"a log-scaled parameter needs positive bounds, got {self.bounds.tolist()}")

    def _transformed(self, values) -> np.ndarray:
        values = np.atleast_2d(np.asarray(values, float))
        return np.where(self.log_scale, np.log(np.maximum(values, 1e-300)), values)

    def to_unit(self, theta: ArrayLike) -> np.ndarray:
        """[m, p] unit-cube coordinates of theta [m, p] (or [p])."""
        low, high = self._transformed(self.bounds[:, 0])[0], self._transformed(self.bounds[:, 1])[0]
        return (self._transformed(theta) - low) / (high - low)

    def from_unit(self, unit: ArrayLike) -> np.ndarray:
        """[m, p] parameters (clipped to the bounds) of unit-cube points unit [m, p] (or [p])."""
        unit = np.atleast_2d(np.asarray(unit, float))
        low, high = self._transformed(self.bounds[:, 0])[0], self._transformed(self.bounds[:, 1])[0]
        values = low + unit * (high - low)
        return np.clip(np.where(self.log_scale, np.exp(values), values), self.bounds[:, 0], self.bounds[:, 1])

    @property
    def centre(self) -> np.ndarray:
        """[p] the parameters at the centre of the unit cube."""
        return self.from_unit(np.full(len(self.bounds), 0.5))[0]


def latin_hypercube(box: ParameterBox, n: int, seed: int) -> np.ndarray:
    """[n, p] seeded Latin-hypercube points, even in the box's unit cube."""
    return box.from_unit(qmc.LatinHypercube(d=len(box.bounds), seed=seed).random(n))


# -- the emulator ---------------------------------------------------------------------------------
class GPEmulator:
    """Emulator of observables [q] over a box of parameters [p]: per output, a linear trend plus a
    Gaussian process (constant x Matern-5/2 with one length scale per parameter, plus white noise
    for the packing scatter and chaotic flow) on the residuals, inputs scaled to the unit cube.

    The linear trend carries the emulator towards the corners of the box, where a zero-mean GP
    fitted to a dozen points would fall back to the mean. The GP is calibration.gp's (shared with
    the Bayesian optimisation); prediction of the mean is done here in numpy, for
    all outputs and many points at once (the fits call it hundreds of thousands of times).
    """

    def __init__(self, box: ParameterBox, seed: int = 0) -> None:
        self.box = box
        self.bounds = box.bounds
        self.seed = seed

    def _unit(self, theta) -> np.ndarray:
        return self.box.to_unit(theta)

    def fit(self, theta: ArrayLike, observed: ArrayLike, previous: GPEmulator | None = None) -> GPEmulator:
        """theta [n, p] within the bounds, observed [n, q].

        previous: an emulator of the same outputs fitted on fewer runs; its hyperparameters start
        the search (one start instead of two, which is what makes a refit after a few added runs cheap).
        """
        u = self._unit(theta)
        observed = np.asarray(observed, float)
        n, p = u.shape
        if observed.shape[0] != n or n < p + 2:
            raise LibraryError(f"emulator: {n} runs for {p} parameters (observed {observed.shape}); need >= {p + 2}")
        self.train_u = u
        design = np.column_stack([np.ones(n), u])
        self.trend, *_ = np.linalg.lstsq(design, observed, rcond=None)  # [p + 1, q]
        residual = observed - design @ self.trend
        self.scale = np.maximum(residual.std(axis=0), 1e-9 * (1 + np.abs(observed).max(axis=0)))
        self.length, self.amplitude, self.alpha, self.noise_std, self.loo = [], [], [], [], []
        for j in range(observed.shape[1]):
            amplitude, length, noise = 1.0, np.full(p, 0.5), 0.1
            if previous is not None:
                amplitude, length = previous.amplitude[j], previous.length[j]
                noise = (previous.noise_std[j] / previous.scale[j]) ** 2
            gp = fit_gp(
                u,
                residual[:, j] / self.scale[j],
                amplitude,
                length,
                float(np.clip(noise, 1e-6, 2.0)),
                amplitude_bounds=(1e-3, 1e2),
                length_bounds=(0.05, 20.0),
                noise_bounds=(1e-6, 2.0),
                alpha=1e-8,
                n_restarts=0 if previous else 1,
                seed=self.seed + j,
            )
            k = gp.kernel_
            self.amplitude.append(k.k1.k1.constant_value)
            self.length.append(np.atleast_1d(k.k1.k2.length_scale) * np.ones(p))
            self.alpha.append(gp.alpha_.ravel())
            self.noise_std.append(np.sqrt(k.k2.noise_level) * self.scale[j])
            # leave-one-out residuals of the GP in closed form (hyperparameters and trend held fixed)
            inverse = np.linalg.inv(k(u) + 1e-8 * np.eye(n))
            self.loo.append((inverse @ (residual[:, j] / self.scale[j])) / np.diag(inverse) * self.scale[j])
        self.length = np.array(self.length)  # [q, p]
        self.amplitude = np.array(self.amplitude)  # [q]
        self.alpha = np.array(self.alpha)  # [q, n]
        self.noise_std = np.array(self.noise_std)  # [q]
        self.loo = np.array(self.loo).T  # [n, q]
        return self

    def predict(self, theta: ArrayLike) -> np.ndarray:
        """[m, q] emulated mean observables at theta [m, p] (or [p] -> [1, q])."""
        return self.predict_unit(self._unit(theta))

    def predict_unit(self, u: ArrayLike) -> np.ndarray:
        """[m, q] emulated mean observables at unit-cube points u [m, p]."""
        u = np.atleast_2d(np.asarray(u, float))
        out = np.column_stack([np.ones(len(u)), u]) @ self.trend
        weight = self.amplitude * self.scale  # [q]
        n, p = self.train_u.shape
        for start in range(0, len(u), 32):  # every output at once, in chunks of points (cache-sized): r [m, n, q]
            chunk = u[start : start + 32]
            squared = (chunk[:, None, :] - self.train_u[None, :, :]) ** 2  # [m, n, p]
            r = np.sqrt(squared.reshape(-1, p) @ self.length.T**-2.0).reshape(len(chunk), n, -1)
            kernel = (1 + np.sqrt(5) * r + 5.0 / 3.0 * r**2) * np.exp(-np.sqrt(5) * r)
            out[start : start + 32] += weight * np.sum(kernel * self.alpha.T, axis=1)
        return out

    def loo_rmse(self) -> np.ndarray:
        """[q] leave-one-out RMS error of the emulator (includes the runs' own scatter)."""
        return np.sqrt(np.mean(self.loo**2, axis=0))
