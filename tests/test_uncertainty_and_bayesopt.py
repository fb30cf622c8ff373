"""Laplace posterior against a linear model with a known answer, held to a nonlinear model's likelihood;
Bayesian optimisation on a known minimum; the optimisers' one interface and history; the one GP of
the emulator and the Bayesian optimisation."""

from pathlib import Path

import numpy as np
import pytest

import calibration.gp
from calibration.bayesopt import BOSettings, bayesian_optimisation
from calibration.emulator import GPEmulator, ParameterBox, latin_hypercube
from calibration.lbfgsb import LBFGSBSettings, multistart_lbfgsb
from calibration.optimise import OptimisationHistory, OptimisationResult, Optimiser, one_at_a_time
from calibration.uncertainty import Z95, finite_difference_jacobian, laplace_posterior, likelihood_checked


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


def two_parameter_posterior(model, theta, bounds, sigma):
    """Laplace posterior of model(theta [2]) -> L* [7] at theta against data model(theta) (exact fit)."""
    jac = finite_difference_jacobian(model, theta, bounds, step=1e-4)
    return laplace_posterior(["friction", "restitution"], theta, jac, np.zeros(7), bounds, sigma=sigma)


def batch(model):
    return lambda points: np.array([model(p) for p in np.atleast_2d(points)])


def test_the_likelihood_check_leaves_a_linear_model_alone_and_widens_where_the_slope_overstates_the_trend():
    """Linear: the chi^2 rise along each interval direction is the linearised one, so no factor.
    Saturating (L* ~ tanh): the Laplace interval is narrower than the likelihood-ratio interval of the
    model itself (whose end, friction alone mattering, solves amplitude^2 tanh^2 / sigma^2 = Z95^2),
    and the check brings it to that end within 5%, the other parameter's interval untouched. A model
    that rises faster than its slope (cubic growth) is kept: the Laplace interval is then the
    conservative one."""
    t = np.linspace(0.5, 3.5, 7)
    theta, bounds, sigma = np.array([0.6, 0.6]), [(0.0, 1.2), (0.0, 1.2)], 0.05

    def linear(p):
        return p[0] * t * 0.1 + 0.05 * p[1]

    post = two_parameter_posterior(linear, theta, bounds, sigma)
    laplace = [value for p in post.parameters for value in (p.low, p.high)]
    checked = likelihood_checked(batch(linear), linear(theta), post, bounds)
    assert checked.likelihood_check["scale"] == pytest.approx([1.0, 1.0], abs=1e-6)
    assert [value for p in checked.parameters for value in (p.low, p.high)] == pytest.approx(laplace)
    assert all(end["crossing"] == pytest.approx(1.0, abs=1e-6) for end in checked.likelihood_check["ends"])

    width = 0.02  # the response saturates beyond ~width from the optimum

    def saturating(p):  # restitution does not matter: the friction's interval is the likelihood's along it
        return 0.1 * t * np.tanh((p[0] - 0.6) / width) + 1e-9 * p[1]

    sigma = 0.25  # noise near the saturated amplitude: the data stop telling values apart at ~1.2 width
    post = two_parameter_posterior(saturating, theta, bounds, sigma)
    laplace_half = post.parameters[0].high - 0.6
    checked = likelihood_checked(batch(saturating), saturating(theta), post, bounds)
    amplitude = np.sqrt(np.sum((0.1 * t) ** 2))  # chi^2 rise = (amplitude tanh(d / width) / sigma)^2
    exact = width * np.arctanh(Z95 * sigma / amplitude)
    checked_half = checked.parameters[0].high - 0.6
    assert laplace_half < 0.8 * exact  # the slope at the optimum overstates the trend
    assert checked_half == pytest.approx(exact, rel=0.05), (laplace_half, checked_half, exact)
    assert checked.likelihood_check["scale"][0] == pytest.approx(checked_half / laplace_half)

    def steepening(p):
        return 0.1 * t * ((p[0] - 0.6) + 20 * (p[0] - 0.6) ** 3) + 0.05 * p[1]

    post = two_parameter_posterior(steepening, theta, bounds, 0.05)
    checked = likelihood_checked(batch(steepening), steepening(theta), post, bounds)
    assert checked.likelihood_check["scale"] == [1.0, 1.0]
    assert checked.likelihood_check["ends"][0]["rise"][0] > Z95**2


def test_the_likelihood_check_finds_a_valley_beyond_a_bump_and_a_failed_probe_counts_against_it():
    """A rough response, as a chaotic rollout's: a narrow dip at the optimum (where the slope is
    steep) in a plateau that lies within Z95^2 of it, with one bump above. The Laplace interval is
    the dip's; the likelihood ratio rules out nothing beyond the bump, so the check widens friction
    to its bounds and calls it not identifiable. The same with every probe failing (NaN) keeps the
    Laplace interval: a failed rollout is no evidence of a flat likelihood."""
    t = np.linspace(0.5, 3.5, 7)
    theta, bounds, sigma = np.array([0.6, 0.6]), [(0.3, 0.9), (0.3, 0.9)], 0.1
    plateau = 0.1 * t / np.sqrt(np.sum(t**2)) * np.sqrt(3.0)  # a chi^2 rise of 3 (< Z95^2) off the dip
    shape = t**2 - np.sum(t**3) / np.sum(t**2) * t  # restitution's response, orthogonal to friction's

    def rough(p):
        dip = np.tanh((p[0] - 0.6) / 0.01)  # steep at the optimum, +-1 beyond ~0.01
        bump = 1.5 * np.exp(-(((p[0] - bump_at[0]) / 0.004) ** 2))
        return plateau * (dip + bump) + p[1] * shape

    bump_at = [np.inf]  # no bump while the slope is taken
    post = two_parameter_posterior(rough, theta, bounds, sigma)
    half = post.parameters[0].high - 0.6
    assert half < 0.05
    bump_at[0] = 0.6 + 1.5 * half  # above the threshold where the probe at 1.5 x the Laplace end lands
    checked = likelihood_checked(batch(rough), rough(theta), post, bounds)
    friction = checked.parameters[0]
    assert not friction.identifiable and (friction.low, friction.high) == (0.3, 0.9), friction
    assert checked.parameters[1].identifiable  # restitution keeps a finite interval
    failing = likelihood_checked(lambda points: np.full((len(points), 7), np.nan), rough(theta), post, bounds)
    assert failing.likelihood_check["scale"] == [1.0, 1.0] and failing.parameters[0].identifiable


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


def test_a_failed_side_of_the_jacobian_falls_back_to_one_side_and_both_sides_flag_the_parameter():
    """A surrogate whose rollout fails (NaN) a step above the optimum: the slope comes from the step
    below and the centre (exact for a linear model); failed on both sides, the parameter is flagged
    with why, and the posterior of the others is still formed (the DAG's calibrated_inverse once
    stopped here with 'non-finite jacobian')."""
    t = np.linspace(0.5, 3.5, 7)
    theta, bounds = np.array([0.85, 0.6]), [(0.3, 0.9), (0.3, 0.9)]

    def model(p, fails=lambda p: p[0] > 0.86):
        return np.full(7, np.nan) if fails(p) else p[0] * t + 0.5 * p[1]

    jac = finite_difference_jacobian(model, theta, bounds, step=0.02, centre=model(theta))
    np.testing.assert_allclose(jac, np.stack([t, np.full(7, 0.5)], axis=1), rtol=1e-9)
    assert np.isnan(finite_difference_jacobian(model, theta, bounds, step=0.02)).any()  # no centre: NaN

    def both_sides_fail(p):
        return model(p, fails=lambda p: abs(p[1] - 0.6) > 1e-9)

    jac = finite_difference_jacobian(both_sides_fail, theta, bounds, step=0.02, centre=model(theta))
    assert np.all(np.isnan(jac[:, 1])) and np.all(np.isfinite(jac[:, 0]))
    post = laplace_posterior(["friction", "restitution"], theta, jac, np.full(7, 0.02), bounds, sigma=0.05)
    friction, restitution = post.parameters
    assert friction.identifiable and friction.std == pytest.approx(0.05 / np.sqrt(np.sum(t**2)), rel=1e-6)
    assert not restitution.identifiable and "either side" in restitution.why
    with pytest.raises(ValueError, match="non-finite residuals"):
        laplace_posterior(["friction", "restitution"], theta, jac, np.full(7, np.nan), bounds, sigma=0.05)


def test_an_untrusted_slope_is_left_out_of_the_posterior():
    """A surrogate's slope in restitution that the simulator it stands for does not show (the DAG's
    gns_only check): restitution's interval is its bounds, flagged with the reason, and friction's is
    what the data give with restitution's column left out, not one narrowed by the spurious slope."""
    t = np.linspace(0.5, 3.5, 7)
    theta, bounds = np.array([0.6, 0.6]), [(0.3, 0.9), (0.3, 0.9)]
    jac = np.stack([t, 0.8 * t + 0.3], axis=1)  # strongly correlated with friction's
    trusted = laplace_posterior(["friction", "restitution"], theta, jac, np.full(7, 0.02), bounds, sigma=0.05)
    why = "the DEM hardly responds to it, the GNS does"
    post = laplace_posterior(
        ["friction", "restitution"], theta, jac, np.full(7, 0.02), bounds, sigma=0.05, untrusted={"restitution": why}
    )
    friction, restitution = post.parameters
    assert trusted.parameters[1].identifiable and (trusted.parameters[1].low, trusted.parameters[1].high) != (0.3, 0.9)
    assert not restitution.identifiable and restitution.why == why and (restitution.low, restitution.high) == (0.3, 0.9)
    assert friction.identifiable and friction.std == pytest.approx(0.05 / np.sqrt(np.sum(t**2)), rel=1e-6)
    assert friction.std < trusted.parameters[0].std  # no longer traded off against restitution


def test_bayesian_optimisation_finds_a_known_minimum_within_budget():
    target = np.array([0.42, 0.71])

    def objective(p):
        return float(np.sum((np.asarray(p) - target) ** 2) + 0.1)

    history = bayesian_optimisation(
        one_at_a_time(objective), [(0.3, 0.9), (0.3, 0.9)], ["friction", "restitution"], BOSettings(20, 6, seed=1)
    ).history
    best, value = history.best
    assert len(history.values) == 20
    assert np.linalg.norm(best - target) < 0.05 and value < 0.1 + 0.0025


def test_both_optimisers_answer_one_call_with_one_history():
    """The same objective, bounds and names through either optimiser: the same result type, the same
    history (every evaluation with its seconds, start and iteration) and the same JSON keys."""

    def batch(points):
        return np.array([float(np.sum((p - [0.42, 0.71]) ** 2) + 0.1 * np.sin(5 * p[0])) for p in points])

    bounds, names = [(0.3, 0.9), (0.3, 0.9)], ["friction", "restitution"]
    optimisers: list[tuple[Optimiser, object]] = [
        (bayesian_optimisation, BOSettings(budget=7, n_initial=4, seed=0)),
        (multistart_lbfgsb, LBFGSBSettings([[0.55, 0.73], [0.35, 0.4]], "finite-difference", max_iterations=4)),
    ]
    results = []
    for optimise, settings in optimisers:
        calls = []
        result = optimise(batch, bounds, names, settings, progress=lambda b, s, v: calls.append((b, s, len(v))))  # noqa: B023
        history = result.history
        assert isinstance(result, OptimisationResult) and type(history) is OptimisationHistory
        columns = ("params", "values", "seconds", "start", "iteration")
        assert {len(getattr(history, c)) for c in columns} == {len(history.values)} and len(history.values) > 1
        assert np.shape(history.params) == (len(history.values), 2) and min(history.seconds) >= 0
        assert result.value == history.best[1] == min(history.values)
        assert result.params == pytest.approx(history.best[0].tolist())
        assert result.n_batches == len(calls) == calls[-1][0] and all(s >= 0 for _, s, _ in calls)
        for k in set(history.start):  # iterations count up within each start
            iterations = [i for i, s in zip(history.iteration, history.start) if s == k]
            assert iterations[0] == 0 and iterations == sorted(iterations)
        results.append(result)
    bo, lbfgsb = results
    assert list(bo.history.to_dict()) == list(lbfgsb.history.to_dict())
    assert bo.history.to_dict()["names"] == lbfgsb.history.to_dict()["names"] == names
    assert set(bo.history.start) == {0} and bo.history.iteration == [0, 0, 0, 0, 1, 2, 3] and bo.starts == []
    assert set(lbfgsb.history.start) == {0, 1}
    for k, run in enumerate(lbfgsb.starts):  # each start's own history is its part of the whole
        assert type(run.evaluations) is OptimisationHistory
        assert run.evaluations.values == [v for v, s in zip(lbfgsb.history.values, lbfgsb.history.start) if s == k]
        assert list(run.to_dict()["evaluations"]) == list(bo.history.to_dict())


def test_the_emulator_and_bayesian_optimisation_fit_the_one_gp(monkeypatch):
    """Both GP users fit their GPs through calibration.gp.fit_gp, the only place in calibration/ that
    builds one."""
    import sklearn.gaussian_process  # fit_gp imports it when it fits (start-up of the jobs that do not)

    fitted = []

    class Counting(sklearn.gaussian_process.GaussianProcessRegressor):
        def fit(self, X, y):
            fitted.append(np.shape(X))
            return super().fit(X, y)

    monkeypatch.setattr(sklearn.gaussian_process, "GaussianProcessRegressor", Counting)
    bounds = [(0.3, 0.9), (0.3, 0.9)]
    bayesian_optimisation(
        one_at_a_time(lambda p: float(np.sum(p**2))), bounds, ["friction", "restitution"], BOSettings(6, 4)
    )
    assert fitted == [(4, 2), (5, 2)]  # one GP per point chosen by expected improvement
    box = ParameterBox(np.array(bounds), (False, False))
    theta = latin_hypercube(box, 8, seed=0)
    GPEmulator(box).fit(theta, np.column_stack([theta.sum(axis=1), np.sin(3 * theta[:, 0])]))
    assert fitted[2:] == [(8, 2), (8, 2)]  # one GP per emulated output
    calibration_dir = Path(calibration.gp.__file__).parent
    builders = {
        path.name
        for path in calibration_dir.glob("*.py")
        if any(f"{name}(" in path.read_text() for name in ("GaussianProcessRegressor", "Matern", "WhiteKernel"))
    }
    assert builders == {"gp.py"}


def test_at_a_corner_of_the_box_the_likelihood_check_probes_along_each_parameter_alone():
    """An optimum at a corner (friction at its lower bound, restitution at its upper, their responses
    correlated): every joint interval direction leaves the box at once, so each parameter is probed
    along its own axis; friction's chi^2 stays within Z95^2 out to its other bound (the dip of the
    rough test above), so it is not identifiable; restitution's rises as its slope says."""
    t = np.linspace(0.5, 3.5, 7)
    theta, bounds, sigma = np.array([0.3, 0.9]), [(0.3, 0.9), (0.3, 0.9)], 0.1
    plateau = 0.1 * t / np.sqrt(np.sum(t**2)) * np.sqrt(3.0)

    def cornered(p):
        return plateau * np.tanh((p[0] - 0.3) / 0.01) + (0.9 - p[1]) * (t**2 + 2 * t)

    post = two_parameter_posterior(cornered, theta, bounds, sigma)
    assert post.correlation[0, 1] > 0.3 and post.parameters[0].identifiable  # up in friction: up in restitution
    checked = likelihood_checked(batch(cornered), cornered(theta), post, bounds)
    friction, restitution = checked.parameters
    assert not friction.identifiable and (friction.low, friction.high) == (0.3, 0.9), friction
    assert restitution.identifiable and checked.likelihood_check["scale"][1] == 1.0
    assert {end["parameter"] for end in checked.likelihood_check["ends"]} == {"friction", "restitution"}
