"""The experimental scaling of a dry column's final deposit (calibration/scaling_laws.py) and a
model's predictions across aspect ratio scored against it."""

import math

import pytest

from calibration.scaling_laws import check_scaling, disc_2d_runout, quasi_2d_height, quasi_2d_runout

ASPECT_RATIOS = [0.5, 1, 2, 3, 4, 5, 6]


def test_the_channel_law_gives_the_lab_figures_and_true_2d_discs_run_out_about_twice_as_far():
    """Lube et al. (2005): 1.2 a below the crossover, 1.9 a^(2/3) above; the two measured columns
    (quartz 6.0 at a = 6, copper 5.2 at a = 5) lie within 7% of it; discs 1.6-2.8x further."""
    laws = [round(quasi_2d_runout(a), 2) for a in ASPECT_RATIOS]
    assert laws == [0.6, 1.2, 2.4, 3.95, 4.79, 5.56, 6.27]
    assert 6.0 / quasi_2d_runout(6) == pytest.approx(1, abs=0.07)
    assert 5.2 / quasi_2d_runout(5) == pytest.approx(1, abs=0.07)
    assert all(1.6 < disc_2d_runout(a) / quasi_2d_runout(a) < 2.8 for a in ASPECT_RATIOS)
    assert disc_2d_runout(1.5) == pytest.approx(3.25 * 1.5**0.96) and disc_2d_runout(2) == pytest.approx(3.8 * 2**0.73)
    # a short column's top stays: H_f = H_i, so H_f / L_i = a; a tall one's deposit is far below H_i
    assert quasi_2d_height(0.5) == 0.5 and quasi_2d_height(1.0) == 1.0
    assert quasi_2d_height(6) == pytest.approx(6**0.4) and quasi_2d_height(6) < 6 / 2.5


def test_predictions_on_the_law_score_zero_and_a_column_that_hardly_moves_is_named_worst():
    on_law = check_scaling(
        ASPECT_RATIOS, [quasi_2d_runout(a) for a in ASPECT_RATIOS], [quasi_2d_height(a) for a in ASPECT_RATIOS]
    )
    assert on_law.runout_error == pytest.approx(0, abs=1e-12) and on_law.height_error == pytest.approx(0, abs=1e-12)
    assert on_law.runout_fraction() == pytest.approx([1.0] * 7)
    # the quartz answer's predictions at size_scale 5 (the report's table): a <= 2 hardly move
    quartz = [0.03, 0.15, 0.29, 2.09, 3.32, 4.31, 6.29]
    heights = [0.50, 0.96, 1.6, 1.5, 1.7, 1.8, 1.9]
    check = check_scaling(ASPECT_RATIOS, quartz, heights)
    assert check.worst_a == 0.5 and check.runout_fraction()[0] == pytest.approx(0.05)
    assert [round(f, 2) for f in check.runout_fraction()[:3]] == [0.05, 0.13, 0.12]
    assert check.runout_error > math.log(2)  # a factor of 2 off on average: not a model of the material
    assert check.height_log_ratio[0] == pytest.approx(0)  # the column that does not fall keeps its height
    # a factor of 2 everywhere is an error of ln 2, whichever way
    assert check_scaling([1, 4], [2.4, 2 * quasi_2d_runout(4)], [1, 1]).runout_error == pytest.approx(math.log(2))
    assert check_scaling([1, 4], [0.6, quasi_2d_runout(4) / 2], [1, 1]).runout_error == pytest.approx(math.log(2))


def test_failed_runs_are_left_out_and_mismatched_lists_refused():
    check = check_scaling([1, 2, 3], [1.2, None, 0.0], [1.0, None, 1.5])
    assert check.runout_log_ratio[1] is None and check.height_log_ratio[1] is None
    assert check.runout_log_ratio[2] == pytest.approx(math.log(0.01))  # no runout: a hundredth, finite
    assert check.worst_a == 3
    assert check_scaling([1], [None], [None]).worst_a is None and math.isnan(
        check_scaling([1], [None], [None]).runout_error
    )
    with pytest.raises(ValueError, match="3 aspect ratios, 2 runouts"):
        check_scaling([1, 2, 3], [1, 2], [1, 2, 3])
