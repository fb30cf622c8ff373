"""The diagnosis' contenders judged by what they predict (calibration/contenders.py): the law as
pseudo-data, the choice by fit and law together, contenders.json's round trip, the words of the
choice. The DEM path (check_contenders on a real diagnosis) runs in the tiny DAG
(tests/test_pipeline_end_to_end.py)."""

import json
import math

import pytest

from calibration.calibrated import CalibrationError
from calibration.contenders import (
    ContenderChoice,
    choose,
    law_chi2,
    resolve_by_prediction,
    score_contender,
)
from calibration.mechanisms import get_mechanisms
from calibration.model import Model
from calibration.scaling_laws import check_scaling, quasi_2d_runout

A = [0.5, 1.0, 2.0, 3.0, 6.0]
LAW = [quasi_2d_runout(a) for a in A]


def contender(name, bic, fractions, packings=2, spread=0.02):
    """A contender whose packings lie `spread` either side of `fractions` [A] of the law."""
    model = Model() if name == "base" else Model(get_mechanisms([name])[0])
    parameters = {"friction": 0.5, "restitution": 0.6}
    if model.mechanism is not None:
        parameters[model.mechanism.parameter] = 0.5 * sum(model.mechanism.bounds)
    each = [[f * law * (1 + spread * (2 * k - 1)) for f, law in zip(fractions, LAW)] for k in range(packings)]
    heights = [[1.0] * len(A) for _ in range(packings)]
    return score_contender(model, parameters, bic, A, each, heights, law_log_std=0.25)


def test_the_laws_chi2_is_the_sum_of_squared_log_misses_over_the_tolerance():
    check = check_scaling(A, [2 * law for law in LAW[:-1]] + [None], [1.0] * len(A))
    # four runs a factor 2 off, one failed: 4 (ln 2 / 0.25)^2; a failed run is left out, not scored
    assert law_chi2(check, 0.25) == pytest.approx(4 * (math.log(2) / 0.25) ** 2)
    assert law_chi2(check_scaling(A, [None] * len(A), [None] * len(A)), 0.25) == math.inf


def test_a_contender_is_scored_on_its_mean_over_packings():
    c = contender("cohesion", 100.0, [1.0] * len(A), spread=0.1)
    # packings at 0.9 and 1.1 of the law: the mean is on it, though neither packing is
    assert c.scaling.final_runout == pytest.approx(LAW)
    assert c.law_chi2 == pytest.approx(0.0, abs=1e-20)
    assert c.combined == pytest.approx(100.0)


def test_the_candidate_that_follows_the_law_wins_a_close_fit():
    # cohesion fits the curve 7.5 better in BIC, but holds the short columns still (5% of the law)
    cohesive = contender("cohesion", 100.0, [0.05, 0.1, 0.3, 0.9, 1.0])
    walls = contender("sidewall_friction", 107.5, [0.9, 0.95, 1.1, 1.0, 1.05])
    base = contender("base", 300.0, [2.5, 2.5, 2.0, 1.9, 1.8])
    chosen, by_fit = choose([base, cohesive, walls])
    assert (chosen, by_fit) == ("sidewall_friction", "cohesion")
    # ... and the fit still decides where both follow the law about equally
    walls_far = contender("sidewall_friction", 107.5, [0.95, 0.95, 1.05, 1.0, 1.0])
    cohesive_on = contender("cohesion", 100.0, [1.0, 1.05, 1.0, 0.95, 1.0])
    assert choose([base, cohesive_on, walls_far]) == ("cohesion", "cohesion")
    # the base model is predicted for contrast, never chosen: the diagnosis' BIC test decides that
    on_law_base = contender("base", 101.0, [1.0] * len(A))
    assert choose([on_law_base, cohesive])[0] == "cohesion"
    with pytest.raises(CalibrationError, match="no candidate mechanism"):
        choose([on_law_base])


def test_contenders_json_round_trips_and_says_why(tmp_path):
    cohesive = contender("cohesion", 100.0, [0.05, 0.1, 0.3, 0.9, 1.0])
    walls = contender("sidewall_friction", 107.5, [0.9, 0.95, 1.1, 1.0, 1.05])
    base = contender("base", 300.0, [2.5, 2.5, 2.0, 1.9, 1.8])
    chosen, by_fit = choose([base, cohesive, walls])
    choice = ContenderChoice("quartz", [base, cohesive, walls], chosen, by_fit, 0.25, "the law", [5001, 5002], 12.0)
    path = tmp_path / "contenders.json"
    choice.to_json(path)
    back = ContenderChoice.read(path)
    assert back.to_dict() == choice.to_dict() == json.loads(path.read_text())
    assert back.contender("cohesion").scaling == cohesive.scaling
    assert "cohesion fits the measured curve best" in choice.why and "sidewall_friction is calibrated" in choice.why
    # the diagnosis' own choice replaced, with the reason kept
    cohesion = Model(get_mechanisms(["cohesion"])[0])
    model, why = resolve_by_prediction(cohesion, "auto: the diagnosis named cohesion.", choice, 0.01)
    assert model.name == "sidewall_friction" and "by the measured curve alone the diagnosis chose cohesion" in why
    same = ContenderChoice("quartz", [base, cohesive], "cohesion", "cohesion", 0.25, "the law", [5001], 1.0)
    model, why = resolve_by_prediction(cohesion, "auto: named.", same, 0.01)
    assert model.name == "cohesion" and why.startswith("auto: named. Judged by its predictions across a too")


def test_a_fitted_value_outside_its_physical_range_is_called_effective():
    c = contender("cohesion", 100.0, [1.0] * len(A))
    mechanism = get_mechanisms(["cohesion"])[0]
    low, high = mechanism.plausible
    inside = (low + high) / 2 if math.isfinite(high) else low + 1
    assert c.physical == (low <= c.parameters[mechanism.parameter] <= high)
    parameters = dict(c.parameters, **{mechanism.parameter: inside})
    c2 = score_contender(Model(mechanism), parameters, 1.0, A, c.runout_each, c.height_each, 0.25)
    assert c2.physical and "effective" not in c2.plausibility
