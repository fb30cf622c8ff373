"""A GNS briefly trained on tiny DEM runs (tests/conftest.py tiny_dataset): it beats the kinematic
baselines on a held-out DEM case, and it recovers a DEM target on the tiny column."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from calibration.compare import case_like
from calibration.gns_objective import GNSObjective
from calibration.recovery import observation_times, packing_scatter, recover_case
from calibration.uncertainty import Z95
from dem.collapse import simulate_collapse
from dem.runout import RunoutMethod, runout_at
from dem.trajectory import read_trajectory
from gns.dataset import read_metadata, read_training_attrs
from gns.evaluate import position_mse
from gns.rollout import rollout_trajectory
from gns.simulator import LearnedSimulator, load_simulator
from gns.train import train
from tests.test_inverse import TINY_MODEL, column_of, untrained_simulator

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def trained_tiny_gns(tiny_dataset, tmp_path_factory):
    """A GNS briefly trained (2000 steps, ~25 s on an idle 2-core box) on the first five tiny DEM runs:
    (simulator, metadata). The sixth run (the valid and test split, mu 0.85, e 0.4) is never trained
    on; with one validation, at the last step, it picks nothing either."""
    metadata_path, _ = tiny_dataset
    folder = tmp_path_factory.mktemp("tiny_gns")
    train(
        metadata_path,
        folder,
        dict(
            TINY_MODEL,
            latent_size=32,
            n_message_passing=3,
            steps=2000,
            validate_every=2000,
            log_every=2000,
            checkpoint_every=2000,
            learning_rate_decay_steps=2000,
        ),
        resume=False,
    )
    metadata = read_metadata(metadata_path)
    return load_simulator(folder / "model_best.pt", metadata), metadata


class KinematicBaseline(LearnedSimulator):
    """No network: the GNS's own update (semi-implicit Euler over a frame, grains kept out of the walls)
    with a fixed acceleration rule. "constant velocity": a = 0, every grain keeps its last input
    velocity; in this second-order update zero acceleration is constant velocity, so the issue's two
    baselines are one. "standing still": a = -v, every grain stays where the input frames left it
    (zero velocity), the second baseline."""

    def __init__(self, simulator: LearnedSimulator, rule: str):
        super().__init__(simulator.config)
        self.load_state_dict(simulator.state_dict())  # the normalisation statistics and bounds
        self.rule = rule

    def forward(self, position_sequence, context):
        velocity = position_sequence[:, -1] - position_sequence[:, -2]
        acceleration = torch.zeros_like(velocity) if self.rule == "constant velocity" else -velocity
        return (acceleration - self.acceleration_mean) / self.acceleration_std


def held_out_position_mse(simulator, dem):
    """Position MSE (mean grain diameters^2) of a rollout of `dem`'s case from its first C frames, over
    the predicted frames; inf for a rollout that failed (left the box)."""
    rollout = rollout_trajectory(simulator, dem, on_invalid="flag")
    if not rollout.attrs["rollout_valid"]:
        return float("inf")
    return position_mse(dem, rollout, simulator.config.n_input_frames) / (2 * float(np.mean(dem.radius))) ** 2


# The GNS must score at most this fraction of the better baseline's position MSE (constant velocity,
# 9.54 d^2 on the held-out run). Measured on that run, training seed 0: 2000 steps 6.28 d^2 (ratio
# 0.66) at ATEN_CPU_CAPABILITY=default and 6.04 (0.63) at AVX2; 600 steps 0.76-0.77. The kernels move
# the ratio by 0.03, so 0.9 leaves 8x that. Other training seeds spread it far more (seeds 1, 2 at
# 2000 steps: 0.33-0.35 and 0.97-0.99; at 600: 0.51-1.38): a GNS this small, on five runs of 77
# grains, is one draw of its training. Untrained GNSs score 27-28 d^2 (2.9x).
BASELINE_MARGIN = 0.9


def test_trained_gns_beats_constant_velocity_and_standing_still_on_a_held_out_dem_case(trained_tiny_gns):
    """The GNS learns DEM physics. Rolled out on a real builtin-DEM run it never trained on (28 frames
    after the first 6), it places the grains closer (position MSE, at most BASELINE_MARGIN of it) than
    the better of two kinematic baselines; an untrained GNS of the same size does not."""
    simulator, metadata = trained_tiny_gns
    dem = read_trajectory(metadata["splits"]["test"][0])
    scores = {rule: held_out_position_mse(KinematicBaseline(simulator, rule), dem) for rule in BASELINES}
    scores["gns"] = held_out_position_mse(simulator, dem)
    scores["untrained gns"] = held_out_position_mse(untrained_simulator(metadata, output_scale=1.0), dem)
    best_baseline = min(scores[rule] for rule in BASELINES)
    assert scores["gns"] <= BASELINE_MARGIN * best_baseline, scores
    assert scores["untrained gns"] > BASELINE_MARGIN * best_baseline, scores  # the bar stops a wrong model


BASELINES = ("constant velocity", "standing still")


def test_recovery_of_a_dem_target_on_the_tiny_column(trained_tiny_gns):
    """A target of known (mu, e), not in the training set: the mean of two DEM packings with noise,
    as a lab averages repeated tests (the issue's tiny-config check, with a looser bound), read through
    the GNS with its own held-out runout error as model error, as the workflow does. On 77 grains the
    DEM runout moves less with mu than between two packings (L* at t/t* = 2.5: 1.97 at mu 0.5, 1.89 at
    0.9, packing std up to 0.18), so no parameter need be identifiable here: what must hold is that the
    packing scatter enters the stated noise, that the reported estimate is the fit the optimiser found
    and fits the target at least as well as the truth and the start do (a wrong estimator fails that),
    that the 95% intervals are the GNS's own likelihood's (the truth inside each, unless the GNS's
    chi^2 at the truth rises above its optimum's by Z95^2: then the surrogate, not the interval,
    rules it out), and that a parameter the posterior calls identifiable is really found (within
    0.15). Measured, training seeds 0-2 at this machine's torch kernels and at
    ATEN_CPU_CAPABILITY=default (6 GNSs): with plain Laplace intervals the truth fell outside one in
    2 of them (and on one other machine's GNS), each time with the GNS's chi^2 at the truth within
    2.9 of its optimum's (< Z95^2 = 3.84): a rough rollout response had made the slope at the
    optimum several times its trend, or an optimum at a bound had clipped a not-identifiable
    parameter's interval. With the likelihood check and a not-identifiable parameter's interval
    its bounds: inside in all 6 (docs/experiments/gns-route.md)."""
    simulator, metadata = trained_tiny_gns
    trained = read_training_attrs(metadata)
    start = simulate_collapse(case_like(trained[0], 0.55, 0.73, seed=99))
    truths = [simulate_collapse(case_like(trained[0], 0.5, 0.6, seed=seed)) for seed in (100, 101)]
    t_points = observation_times(3.0)
    runout = RunoutMethod()  # the config's default, for the targets and the inverse design
    held_out = read_trajectory(metadata["splits"]["test"][0])
    # the GNS's error at each t/t* point (one held-out case: its absolute difference)
    model_error = np.abs(
        runout_at(rollout_trajectory(simulator, held_out), t_points, runout) - runout_at(held_out, t_points, runout)
    )
    curves = np.array([runout_at(t, t_points, runout) for t in truths])
    row = recover_case(
        simulator,
        metadata,
        trained,
        start,
        truths,
        t_points,
        noise_std=0.05,
        seed=0,
        n_starts=2,
        max_iterations=10,
        runout=runout,
        model_error_std=model_error,
    )
    # the stated std is that of a mean of 2 packings: sqrt(noise^2 + s^2 / 2), s from the two runs
    scatter = np.abs(curves[0] - curves[1]) / np.sqrt(2)
    assert row["packings"] == 2 and np.allclose(row["packing_std"], scatter)
    assert np.allclose(row["measured_std"], np.sqrt(0.05**2 + scatter**2 / 2))
    # the posterior's noise: the target's, the GNS's error at each point and the scatter of the packing it rolls out
    assert np.allclose(row["posterior_std"], np.sqrt(np.square(row["measured_std"]) + model_error**2 + scatter**2))
    assert np.abs(np.array(row["measured"]) - curves.mean(0)).max() < 4 * 0.05
    assert row["objective"] < row["start_objective"]
    # the estimate is the optimiser's fit: the GNS objective there is the reported one, and no worse
    # than at the truth or at the start
    target = column_of(start, t_points, row["measured"], name="target_again")
    fits = GNSObjective(simulator, start, target, runout=runout).values([row["estimate"], row["truth"], [0.55, 0.73]])
    assert fits[0] == pytest.approx(row["objective"], rel=1e-5, abs=1e-7), (fits, row)
    assert fits[0] <= min(fits[1:]), (fits, row)
    # the GNS's chi^2 at the truth over its optimum's, under the posterior's own noise
    at_estimate, at_truth = (
        np.sum(np.square((curve - np.array(row["measured"])) / np.array(row["posterior_std"])))
        for curve in GNSObjective(simulator, start, target, runout=runout).runout_values(
            [row["estimate"], row["truth"]]
        )
    )
    for k, inside in enumerate(row["inside"]):
        assert inside or at_truth - at_estimate > Z95**2, (k, at_truth, at_estimate, row)
    for k, (low, high) in enumerate(row["interval"]):
        assert low <= row["estimate"][k] <= high, row
        if row["identifiable"][k]:
            assert abs(row["estimate"][k] - row["truth"][k]) <= 0.15, row
        else:  # reported as unknown, not given a false precision
            assert high - low > 0.5 * (0.9 - 0.3), row
    assert row["truth"] == [0.5, 0.6] and row["t_over_tstar"] == [0.5, 1.0, 1.5, 2.0, 2.5]


def test_packing_scatter_pools_targets_without_their_differences():
    a = np.array([[1.0, 2.0], [1.2, 2.4]])  # target 1: two packings
    b = np.array([[5.0, 9.0], [5.2, 8.6], [5.1, 8.8]])  # target 2, far away: its offset is no scatter
    std, dof = packing_scatter([a, b])
    expected = np.sqrt((np.sum((a - a.mean(0)) ** 2, 0) + np.sum((b - b.mean(0)) ** 2, 0)) / 3)
    assert dof == 3 and np.allclose(std, expected)
    with pytest.raises(ValueError, match="at least two packings"):
        packing_scatter([a[:1]])
