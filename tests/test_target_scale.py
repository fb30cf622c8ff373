"""The answer carried to the target size_scale (calibration/target_scale.py): the coarse star
design, the correction's steps at the target, its validation there, and the record."""

import math
from dataclasses import replace

import numpy as np
import pytest

from calibration.calibrated import Validation, model_runout
from calibration.confirmation import CONFIRM_SEED0, Confirmation
from calibration.mechanisms import get_mechanisms
from calibration.model import Model
from calibration.target_scale import STAR_STEP, calibrate_at_target, predict_finer, resolution_shift, star_points
from tests.test_calibrated import COLUMN, RUNOUT, SETTINGS

COARSE = SETTINGS  # the tiny quartz column (a = 2, L_i = 0.01 m) at size_scale 4: 77 grains


def test_the_star_design_steps_each_parameter_both_ways_in_the_unit_box_and_stays_inside_it():
    model = Model()
    points = star_points(model, [0.3, 0.6])  # friction at its lower bound
    unit = model.box.to_unit(points)
    centre = model.box.to_unit([0.3, 0.6])[0]
    assert points.shape == (5, 2) and points[0] == pytest.approx([0.3, 0.6])
    assert unit[1] == pytest.approx(centre)  # the arm below the bound is the centre itself
    assert unit[2] == pytest.approx(centre + [STAR_STEP, 0])
    assert unit[3] == pytest.approx(centre - [0, STAR_STEP]) and unit[4] == pytest.approx(centre + [0, STAR_STEP])
    assert np.all((unit >= 0) & (unit <= 1))


def test_the_coarse_answer_is_corrected_at_the_target_along_the_coarse_slopes():
    """A measurement made at the target (size_scale 3.5) with side-wall friction 0.05 on the
    correction's own packings, and a coarse answer at 0.25: the star runs at the coarse scale, the
    steps at the target, and the lowest target MSE is chosen, with mu_w nearer the truth; it is
    validated at the target on the validation packings. Measured on an AMD EPYC: the start 0.056,
    the steps 0.029 and 0.014 (mu_w 0.175, 0.116); from 0.25 towards 0.1 and from 0.03 towards 0.2
    the same (0.023 -> 0.003, 0.048 -> 0.036): the test asks half the start's MSE."""
    model = Model(get_mechanisms(["sidewall_friction"], 0.01)[0])
    truth, start = [0.5, 0.6, 0.05], [0.5, 0.6, 0.25]
    target = replace(COARSE, size_scale=3.5)
    seeds = [CONFIRM_SEED0, CONFIRM_SEED0 + 1]
    runout = np.mean([model_runout(model, COLUMN, truth, target, s, RUNOUT, None) for s in seeds], axis=0)
    column = replace(COLUMN, runout=runout)
    carried = calibrate_at_target(model, column, start, COARSE, 3.5, RUNOUT, None, 2, 2, 2)
    assert carried.size_scale == 3.5 and carried.coarse_size_scale == 4.0
    assert [v.seeds for v in carried.slopes] == [seeds] * 7 and carried.coarse_runs == 14
    first = carried.correction.candidates[0]
    assert first.parameters == dict(zip(model.parameter_names, start)) and first.seeds == seeds
    # the same parameters and packings at the two scales: other grains, another curve
    assert first.mean != carried.slopes[0].mean
    scores = [c.mse for c in carried.correction.checked]
    chosen = carried.correction.checked[carried.correction.chosen]
    assert carried.correction.chosen == int(np.argmin(scores)) and chosen.mse < first.mse / 2, scores
    assert abs(chosen.parameters["sidewall_friction"] - truth[2]) < abs(start[2] - truth[2])
    assert carried.validation.seeds == [5001, 5002] and carried.theta == list(chosen.parameters.values())
    record = carried.to_dict()
    assert record["coarse_runs"] == 14 and record["target_runs"] == 2 * (1 + len(carried.correction.steps)) + 2
    assert record["validation"]["parameters"] == chosen.parameters and len(record["slopes"]) == 7


def test_the_resolution_shift_is_the_curves_own_move_and_bounds_the_transfer_from_below():
    coarse = [1.0, 2.0, 3.0, None]
    fine = [1.5, 2.5, 3.5, 4.0]  # 0.5 farther at every time both ran
    shift, least = resolution_shift(coarse, fine, fit_mse=0.04)
    assert shift == pytest.approx(0.25)
    assert least == pytest.approx((0.5 - 0.2) ** 2)
    # a measured curve 0.2 short of the coarse one everywhere meets that bound's worst case
    measured = np.array([0.8, 1.8, 2.8])
    assert np.mean((np.array(fine[:3]) - measured) ** 2) >= least
    assert resolution_shift(coarse, coarse, fit_mse=0.04) == (0.0, pytest.approx(0.04))
    assert resolution_shift([None, 1.0], [2.0, None], fit_mse=0.1) == (None, None)


def linear_validation(model, unit, mean, label="point"):
    """A Validation of 4 packings at the unit-box point `unit` with mean curve `mean` and a scatter far
    below the steps (so the damped step is the plain Gauss-Newton one)."""
    mean = [float(m) for m in mean]
    return Validation(
        route=label,
        parameters=dict(zip(model.parameter_names, model.box.from_unit(np.asarray(unit, float))[0])),
        seeds=[CONFIRM_SEED0 + k for k in range(4)],
        t_over_tstar=[0.5, 1.0, 2.0, 3.0],
        curves=[mean] * 4,
        failed={},
        mean=mean,
        std=[1e-9] * len(mean),
        mse=0.0,
        mse_each=[0.0] * 4,
        seconds=0.0,
    )


def test_the_finer_answer_undoes_a_runout_that_grows_linearly_in_log_grain_size():
    """A model whose L* curve is linear in the unit-box parameters and in log size_scale (L = a + J u
    - b ln s: finer grains run farther), measured at the finer scale 2 with parameters u*: from the
    coarse star at 5 and the target's answer at 3 (anywhere near u*), predict_finer's parameters are
    u*, its predicted curve the measured one. A wrong sign or share of the shift, or a step along the
    wrong slope, lands elsewhere."""
    model = Model()
    a, b = np.array([0.2, 0.8, 1.9, 2.6]), np.array([0.3, 0.6, 0.9, 1.1])
    J = np.array([[-0.5, 0.1], [-1.2, 0.2], [-2.0, 0.4], [-2.4, 0.3]])

    def curve(u, size_scale):
        return a + J @ np.asarray(u, float) - b * np.log(size_scale)

    truth, coarse_answer, target_answer = np.array([0.45, 0.55]), np.array([0.6, 0.5]), np.array([0.55, 0.4])
    column = replace(COLUMN, t_over_tstar=np.array([0.5, 1.0, 2.0, 3.0]), runout=curve(truth, 2.0))
    star = [
        linear_validation(model, u, curve(u, 5.0))
        for u in model.box.to_unit(star_points(model, model.box.from_unit(coarse_answer)[0]))
    ]
    start = linear_validation(model, coarse_answer, curve(coarse_answer, 3.0), "start")
    chosen = linear_validation(model, target_answer, curve(target_answer, 3.0), "step")
    correction = Confirmation([start], [0.0], 1, steps=[chosen])  # no slope kept: the star's own
    finer = predict_finer(model, column, star, correction, 5.0, 3.0, 2.0)
    assert finer.factor == pytest.approx(math.log(1.5) / math.log(5 / 3))
    assert finer.shift == pytest.approx((-b * math.log(3 / 5)).tolist())  # finer grains: farther at every time
    assert finer.theta == pytest.approx(model.box.from_unit(truth)[0].tolist(), abs=1e-6)
    assert finer.predicted == pytest.approx(column.runout.tolist(), abs=1e-6) and finer.predicted_mse < 1e-10
    # the answer at the target itself, run at the finer scale, misses by the whole move
    assert np.mean((curve(target_answer, 2.0) - column.runout) ** 2) > 0.01
    # no slope to step along (a failed start): no prediction
    failed = replace(start, mean=[math.nan] * 4)
    assert predict_finer(model, column, star, Confirmation([failed], [0.0], 1, steps=[chosen]), 5.0, 3.0, 2.0) is None
