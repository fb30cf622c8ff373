"""Laplace posterior against a linear model with a known answer; Bayesian optimisation on a known minimum."""

import numpy as np
import pytest

from calibration.bayesopt import bayesian_optimisation
from calibration.uncertainty import finite_difference_jacobian, laplace_posterior


def test_laplace_posterior_matches_linear_least_squares():
    rng = np.random.default_rng(0)
    t = np.linspace(0.5, 3.5, 7)
    design = np.stack([t, np.ones_like(t)], axis=1)  # L* = mu_effect * t + offset
    truth = np.array([0.6, 0.4])
    sigma = 0.05
    data = design @ truth + rng.normal(0, sigma, len(t))
    optimum, *_ = np.linalg.lstsq(design, data, rcond=None)
    post = laplace_posterior(
        ["slope", "offset"], optimum, design, design @ optimum - data, bounds=[(0, 2), (-2, 2)], sigma=sigma
    )
    expected = sigma**2 * np.linalg.inv(design.T @ design)
    assert np.allclose(post.covariance, expected, rtol=1e-6)
    assert post.correlation[0, 1] == pytest.approx(expected[0, 1] / np.sqrt(expected[0, 0] * expected[1, 1]))
    assert all(p.identifiable for p in post.parameters)
    assert post.parameters[0].low < truth[0] < post.parameters[0].high


def test_a_parameter_the_data_cannot_see_is_flagged_not_given_false_precision():
    t = np.linspace(0.5, 3.5, 7)

    def model(theta):
        return theta[0] * t + 1e-7 * theta[1]  # restitution barely matters

    theta = np.array([0.5, 0.6])
    bounds = [(0.3, 0.9), (0.3, 0.9)]
    jac = finite_difference_jacobian(model, theta, bounds)
    post = laplace_posterior(["friction", "restitution"], theta, jac, np.full(7, 0.02), bounds, sigma=0.05)
    friction, restitution = post.parameters
    assert friction.identifiable and not restitution.identifiable
    assert "hardly changes" in restitution.why
    assert (restitution.low, restitution.high) == (0.3, 0.9)


def test_bayesian_optimisation_finds_a_known_minimum_within_budget():
    target = np.array([0.42, 0.71])

    def objective(p):
        return float(np.sum((np.asarray(p) - target) ** 2) + 0.1)

    history = bayesian_optimisation(
        objective, [(0.3, 0.9), (0.3, 0.9)], ["friction", "restitution"], budget=20, n_initial=6, seed=1
    )
    best, value = history.best
    assert len(history.values) == 20
    assert np.linalg.norm(best - target) < 0.05 and value < 0.1 + 0.0025
