"""L-BFGS-B for the inverse design (calibration/lbfgsb.py): the float32 finite-difference step, the
multi-start in lockstep, scaled steps, batched stencils, stopping, and failing evaluations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from calibration.geometry import InverseDesignError
from calibration.lbfgsb import (
    FD_STEP,
    FTOL,
    GTOL,
    MAX_LINE_SEARCH,
    SCIPY_DEFAULT_STEP,
    STALL_EVALUATIONS,
    LBFGSBSettings,
    check_step,
    multistart_lbfgsb,
    step_vanishes,
)


# -- float32 finite-difference steps -----------------------------------------------------------------------
def test_scipy_default_step_vanishes_in_float32_and_the_sound_step_does_not():
    assert np.float32(0.31) + np.float32(1e-8) == np.float32(0.31)
    assert step_vanishes(0.31, SCIPY_DEFAULT_STEP) and step_vanishes(0.7, SCIPY_DEFAULT_STEP)
    assert not step_vanishes(0.31, SCIPY_DEFAULT_STEP, dtype=np.float64)
    assert not any(step_vanishes(v, FD_STEP) for v in (0.3, 0.6, 0.9))
    with pytest.raises(InverseDesignError, match="vanishes in float32 at 0.3"):
        check_step(SCIPY_DEFAULT_STEP, [(0.3, 0.9)])
    check_step(FD_STEP, [(0.3, 0.9)])


# -- multi-start in lockstep -----------------------------------------------------------------------------
def _bowl(x):
    return 3 * (x[0] - 0.42) ** 2 + (x[1] - 0.71) ** 2 + 0.5 * (x[0] - 0.42) * (x[1] - 0.71) + 0.1 * np.sin(5 * x[0])


def _bowl_gradient(x):
    return np.array(
        [6 * (x[0] - 0.42) + 0.5 * (x[1] - 0.71) + 0.5 * np.cos(5 * x[0]), 2 * (x[1] - 0.71) + 0.5 * (x[0] - 0.42)]
    )


def test_lockstep_multistart_batches_points_and_follows_the_paths_of_lone_runs():
    starts = np.array([[0.55, 0.73], [0.3, 0.3], [0.9, 0.9], [0.8, 0.35]])
    batch_sizes = []

    def batch(points):
        batch_sizes.append(len(points))
        return np.array([_bowl(p) for p in points]), np.array([_bowl_gradient(p) for p in points])

    result = multistart_lbfgsb(batch, [(0.3, 0.9)] * 2, ["friction", "restitution"], LBFGSBSettings(starts))
    runs, n_batches = result.starts, result.n_batches
    assert n_batches == len(batch_sizes) and batch_sizes[0] == 4
    assert sum(batch_sizes) == sum(len(r.evaluations.values) for r in runs) > n_batches
    for start, run in zip(starts, runs):
        lone = minimize(
            lambda x: (_bowl(x), _bowl_gradient(x)),
            start,
            jac=True,
            method="L-BFGS-B",
            bounds=[(0.3, 0.9)] * 2,
            options={"maxiter": 20, "ftol": FTOL, "gtol": GTOL, "maxls": 10, "maxfun": 40},
        )
        assert np.allclose(run.params, lone.x, rtol=0, atol=1e-12) and run.n_iterations == lone.nit
        assert run.iterates[0][0] == start.tolist() and run.iterates[-1][0] == pytest.approx(run.params)
        assert run.value == pytest.approx(_bowl(lone.x))


def test_scaled_steps_let_lbfgsb_solve_parameters_of_very_different_ranges():
    """Friction in [0.3, 0.9] beside a Bond number in [0, 60]: L-BFGS-B stepping in x / scale (scale
    = range / 0.6) reaches the minimum of a bowl that is round in those units; every point it
    reports is in natural units, inside the bounds."""
    bounds, names, target = [(0.3, 0.9), (0.0, 60.0)], ["friction", "bond_number"], np.array([0.45, 42.0])
    scale = np.array([1.0, 100.0])

    def batch(points):
        z = (np.asarray(points) - target) / scale
        return (z**2).sum(axis=1), 2 * z / scale

    starts = np.array([[0.55, 0.0], [0.85, 55.0]])
    scaled = multistart_lbfgsb(batch, bounds, names, LBFGSBSettings(starts, scale=scale))
    assert np.allclose(scaled.params, target, atol=1e-6) and scaled.value < 1e-10
    for run, start in zip(scaled.starts, starts):
        points = np.array([p for p, _ in run.iterates])
        assert np.all(points >= [0.3, 0.0]) and np.all(points <= [0.9, 60.0])
        assert run.start == pytest.approx(start.tolist()) and points[0] == pytest.approx(start)
    # scale 1 is the unscaled optimiser, point for point
    plain = multistart_lbfgsb(batch, bounds, names, LBFGSBSettings(starts))
    ones = multistart_lbfgsb(batch, bounds, names, LBFGSBSettings(starts, scale=np.ones(2)))
    assert plain.params == ones.params and plain.history.values == ones.history.values


def test_finite_difference_stencils_run_as_one_batch_and_follow_scipys_own_differences():
    """Each start's forward-difference stencil (x, x + h e_j; backwards at an upper bound) is one
    batch of P + 1 points, and the path is the one scipy takes with eps = h."""
    starts = np.array([[0.55, 0.73], [0.9, 0.3]])  # the second sits on an upper bound
    batch_sizes = []

    def batch(points):
        batch_sizes.append(len(points))
        return np.array([_bowl(p) for p in points])

    settings = LBFGSBSettings(starts, gradient="finite-difference", fd_step=FD_STEP)
    result = multistart_lbfgsb(batch, [(0.3, 0.9)] * 2, ["friction", "restitution"], settings)
    runs, n_batches = result.starts, result.n_batches
    assert batch_sizes[0] == 2 * 3 and n_batches == len(batch_sizes)
    for start, run in zip(starts, runs):
        lone = minimize(
            _bowl,
            start,
            method="L-BFGS-B",
            bounds=[(0.3, 0.9)] * 2,
            options={"maxiter": 20, "ftol": FTOL, "gtol": GTOL, "maxls": 10, "maxfun": 40, "eps": FD_STEP},
        )
        assert np.allclose(run.params, lone.x, rtol=0, atol=1e-9) and run.n_iterations == lone.nit


def test_a_start_that_stops_improving_stops_instead_of_retrying_its_line_search():
    """A rough objective as a rollout makes it: flat to within noise, with a large local gradient."""

    def batch(points):
        noise = 1e-6 * np.sin(1e4 * points[:, 0])
        return 1.0 + noise, np.tile([50.0, -80.0], (len(points), 1))

    settings = LBFGSBSettings([[0.55, 0.73]], max_iterations=20)
    runs = multistart_lbfgsb(batch, [(0.3, 0.9)] * 2, ["friction", "restitution"], settings).starts
    assert len(runs[0].evaluations.values) == 1 + STALL_EVALUATIONS < MAX_LINE_SEARCH
    assert "without improvement" in runs[0].message and runs[0].value == min(runs[0].evaluations.values)


def test_lockstep_reports_a_failing_evaluation_instead_of_hanging():
    def batch(points):
        raise InverseDesignError("GNS objective is not finite at friction=0.5")

    with pytest.raises(InverseDesignError, match="not finite"):
        multistart_lbfgsb(
            batch, [(0.3, 0.9)] * 2, ["friction", "restitution"], LBFGSBSettings([[0.5, 0.5], [0.6, 0.6]])
        )


def test_a_point_where_the_objective_is_not_finite_is_recorded_and_only_its_start_stops():
    """A GNS rollout that diverges at one point (NaN there) costs that start, not the inverse design."""

    def batch(points):  # the bowl, but NaN (a diverged rollout) for friction above 0.8
        values = np.array([_bowl(p) if p[0] <= 0.8 else np.nan for p in points])
        return values, np.array([_bowl_gradient(p) for p in points])

    starts = [[0.55, 0.73], [0.85, 0.5], [0.78, 0.3]]  # the second fails at its start
    result = multistart_lbfgsb(batch, [(0.3, 0.9)] * 2, ["friction", "restitution"], LBFGSBSettings(starts))
    assert [r.start for r in result.starts] == [starts[0], starts[2]]  # the failed start has no result
    failed = result.history.failed
    assert failed[0]["params"] == starts[1] and failed[0]["start"] == 1 and "not finite" in failed[0]["reason"]
    assert all(f["params"][0] > 0.8 for f in failed) and not any(np.isnan(result.history.values))
    lone = minimize(
        lambda x: (_bowl(x), _bowl_gradient(x)),
        starts[0],
        jac=True,
        method="L-BFGS-B",
        bounds=[(0.3, 0.9)] * 2,
        options={"maxiter": 20, "ftol": FTOL, "gtol": GTOL, "maxls": 10, "maxfun": 40},
    )
    assert result.starts[0].params == pytest.approx(lone.x.tolist(), abs=1e-9)  # the others go on as alone
    with pytest.raises(InverseDesignError, match=r"no start could be evaluated: .*friction.*0.85.*not finite"):
        multistart_lbfgsb(batch, [(0.3, 0.9)] * 2, ["friction", "restitution"], LBFGSBSettings([[0.85, 0.5]]))
