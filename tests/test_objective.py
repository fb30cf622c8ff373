"""The shared calibration objective: runout MSE at the measured t/t* points."""

import math

import numpy as np
import pytest

from calibration.measured import load_column
from calibration.objective import ObjectiveError, objective, objective_from_curve, runout_mse
from dem.runout import RunoutMethod
from dem.trajectory import Trajectory

QUARTZ = "data/measured/quartz_a6.csv"
# front_trajectory builds a connected-deposit front, the rule these tests were written for
CONNECTED = RunoutMethod("connected_front")


def front_trajectory(front, L_i=0.02, aspect_ratio=6.0, t_star=0.11, dt_frame=None, radius=5e-4, n_chain=200):
    """A synthetic trajectory whose connected-deposit front is exactly front[k] (m) at frame k.

    A chain of grains along the floor from the wall to the front (overlapping is fine: the runout
    only needs them connected) and a stack of 8 grains at the front, so the 8 leading grains all
    end at x + r = front[k].
    """
    front = np.asarray(front, float)
    frames = []
    for L in front:
        chain = np.column_stack([np.linspace(radius, L - radius, n_chain), np.full(n_chain, radius)])
        stack = np.column_stack([np.full(8, L - radius), radius * (3 + 2 * np.arange(8))])
        frames.append(np.vstack([chain, stack]))
    n = n_chain + 8
    attrs = dict(
        engine="synthetic",
        engine_version="0",
        L_i=L_i,
        H_i=aspect_ratio * L_i,
        aspect_ratio=aspect_ratio,
        material="quartz",
        dt_frame=dt_frame or t_star / 4,
        t_star=t_star,
        x_min=0.0,
        x_max=0.5,
        y_min=0.0,
        y_max=0.35,
        seed=0,
        friction=0.5,
        restitution=0.6,
    )
    return Trajectory(
        positions=np.array(frames, np.float32),
        radius=np.full(n, radius),
        particle_type=np.zeros(n, np.int32),
        attrs=attrs,
    )


def test_runout_mse_value():
    assert runout_mse(np.array([1.0, 2.0, 4.0]), np.array([1.0, 3.0, 2.0])) == pytest.approx(5.0 / 3.0)
    with pytest.raises(ObjectiveError, match="3 points, measured 2"):
        runout_mse(np.zeros(3), np.zeros(2))


def test_runout_mse_is_differentiable_in_torch():
    torch = pytest.importorskip("torch")
    simulated = torch.tensor([1.0, 2.0], dtype=torch.float64, requires_grad=True)
    loss = runout_mse(simulated, torch.tensor([0.0, 0.0], dtype=torch.float64))
    loss.backward()
    assert loss.item() == pytest.approx(2.5)
    np.testing.assert_allclose(simulated.grad.numpy(), [1.0, 2.0])  # d/dx mean(x^2) = 2x/K


def test_objective_from_curve_interpolates_at_measured_times():
    measured = load_column(QUARTZ)
    t = np.linspace(0, 4, 81)
    curve = np.interp(t, measured.t_over_tstar, measured.runout)  # piecewise linear through the points
    assert objective_from_curve(t, curve, measured) == pytest.approx(0.0, abs=1e-12)
    assert objective_from_curve(t, curve + 0.5, measured) == pytest.approx(0.25)
    with pytest.raises(ObjectiveError, match=r"t/t\* = \[3.5\] fall outside the simulated window") as info:
        objective_from_curve(t[t <= 3.0], curve[t <= 3.0], measured)
    assert QUARTZ in str(info.value)
    with pytest.raises(ObjectiveError, match="must increase"):
        objective_from_curve(t[::-1], curve, measured)


def test_objective_of_a_trajectory():
    measured = load_column(QUARTZ)
    t_over_tstar = np.arange(0, 4.01, 0.25)
    runout = np.interp(t_over_tstar, measured.t_over_tstar, measured.runout, left=0.0) + 0.5
    traj = front_trajectory(measured.L_i * (1 + runout))
    np.testing.assert_allclose(traj.t_over_tstar, t_over_tstar)
    assert objective(traj, measured, CONNECTED) == pytest.approx(0.25, rel=1e-4)


def test_objective_refuses_another_column_or_a_short_window():
    measured = load_column(QUARTZ)
    fronts = 0.02 * (1 + np.linspace(0, 6, 17))
    with pytest.raises(ObjectiveError, match="aspect_ratio = 5 differs"):
        objective(front_trajectory(fronts, aspect_ratio=5.0), measured, CONNECTED)
    with pytest.raises(ObjectiveError, match="L_i = 0.01 differs"):
        objective(front_trajectory(fronts / 2, L_i=0.01), measured, CONNECTED)
    short = front_trajectory(fronts[:13])  # t/t* up to 3.0
    with pytest.raises(ObjectiveError, match=r"\[3.5\] fall outside"):
        objective(short, measured, CONNECTED)
    assert math.isfinite(objective(front_trajectory(fronts), measured, CONNECTED))
