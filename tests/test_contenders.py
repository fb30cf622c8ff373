"""The diagnosis' contenders judged by what they predict (calibration/contenders.py): the law as
pseudo-data, the choice by fit and law together, contenders.json's round trip, the words of the
choice. The DEM path (check_contenders on a real diagnosis) runs in the tiny DAG
(tests/test_pipeline_end_to_end.py)."""

import json
import math

import numpy as np
import pytest

from calibration.calibrated import CalibrationError
from calibration.contenders import (
    ContenderChoice,
    choose,
    contender_pairs,
    deciding_column,
    law_chi2,
    resolve_by_prediction,
    score_contender,
)
from calibration.grain_shift import GrainShift, debiased_squares
from calibration.mechanisms import MechanismError, get_mechanisms
from calibration.model import Model, model_named
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
    trio = [base, cohesive, walls]
    choice = ContenderChoice(
        "quartz", trio, chosen, by_fit, 0.25, "the law", [5001, 5002], 12.0, 0.02, deciding_column(trio, 0.02)
    )
    path = tmp_path / "contenders.json"
    choice.to_json(path)
    back = ContenderChoice.read(path)
    assert back.to_dict() == choice.to_dict() == json.loads(path.read_text())
    assert back.contender("cohesion").scaling == cohesive.scaling and back.deciding == choice.deciding
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


def test_the_deciding_column_is_where_the_two_best_part_most_against_the_packing_scatter():
    # the two candidates agree at large a and part at small a; the base model, far off, is not one of them
    cohesive = contender("cohesion", 100.0, [0.05, 0.1, 0.3, 0.9, 1.0], spread=0.05)
    walls = contender("sidewall_friction", 107.5, [0.9, 0.95, 1.1, 1.0, 1.05], spread=0.05)
    base = contender("base", 300.0, [2.5, 2.5, 2.0, 1.9, 1.8], spread=0.05)
    d = deciding_column([base, cohesive, walls], L_i=0.02)
    assert d.models == ["sidewall_friction", "cohesion"] and d.L_i == 0.02
    runout = {c.model: c.scaling.final_runout for c in (cohesive, walls)}
    # the separation by hand: |difference| over the pooled one-packing std times sqrt(1/2 + 1/2)
    separations = []
    for k in range(len(A)):
        residuals = [
            v - m
            for c in (base, cohesive, walls)
            for v, m in zip((e[k] for e in c.runout_each), [c.scaling.final_runout[k]] * 2)
        ]
        scatter = math.sqrt(sum(r * r for r in residuals) / 3)
        separations.append(abs(runout["cohesion"][k] - runout["sidewall_friction"][k]) / scatter)
    k = max(range(len(A)), key=separations.__getitem__)
    assert d.aspect_ratio == A[k] and d.separation == pytest.approx(separations[k])
    # one packing each: no scatter, the largest difference ranks
    single = [
        contender(m, b, f, packings=1)
        for m, b, f in (
            ("cohesion", 100.0, [0.05, 0.1, 0.3, 0.9, 1.0]),
            ("sidewall_friction", 107.5, [0.9, 0.95, 1.1, 1.0, 1.05]),
        )
    ]
    d1 = deciding_column(single, L_i=0.02)
    assert d1.separation is None and d1.scatter is None and d1.aspect_ratio == 2.0
    assert deciding_column(single[:1], L_i=0.02) is None


def test_the_report_names_the_experiment_that_would_decide():
    from pipeline.contenders_section import contenders_lines

    cohesive = contender("cohesion", 100.0, [0.05, 0.1, 0.3, 0.9, 1.0])
    walls = contender("sidewall_friction", 103.0, [0.9, 0.95, 1.1, 1.0, 1.05])
    close = [contender("base", 300.0, [2.5] * len(A)), cohesive, walls]
    chosen, by_fit = choose(close)
    choice = ContenderChoice(
        "q", close, chosen, by_fit, 0.25, "the law", [1, 2], 1.0, 0.02, deciding_column(close, 0.02)
    )
    text = "\n".join(contenders_lines(choice))
    d = choice.deciding
    assert f"A column of a = {d.aspect_ratio:g} at L_i = 0.02 m" in text and "Measuring it tells them apart" in text
    assert "within the margin" not in text  # the law parts them by far more than the decision margin of 6
    # every contender a row: its fraction of the law per a, 'no: effective' for a Bond number of 30
    rows = [line for line in text.splitlines() if line.startswith("| ") and "BIC" not in line and "---" not in line]
    assert len(rows) == 3 and "no: effective" in rows[1] and "**sidewall_friction**" in rows[2]
    # two candidates on the law alike, 3 apart in BIC: within the margin, the data do not decide
    even = [contender("cohesion", 100.0, [1.0] * len(A)), contender("sidewall_friction", 103.0, [1.01] * len(A))]
    tie = ContenderChoice("q", even, *choose(even), 0.25, "the law", [1, 2], 1.0, 0.02, deciding_column(even, 0.02))
    assert "within the margin of 6: the data do not decide" in "\n".join(contenders_lines(tie))
    # ... so of the two the one with physical values is calibrated (a Bond number of 30 is effective)
    assert (tie.chosen, tie.by_fit) == ("sidewall_friction", "cohesion")
    assert "within the margin of 6 the data do not tell apart, and its parameters are physical" in tie.why
    assert choose(even, margin=2.0)[0] == "cohesion"  # 3 apart: told apart by a margin of 2


def test_auto_pairs_the_two_best_single_candidates_and_a_bad_pair_names_its_key():
    cohesive = contender("cohesion", 100.0, [0.05, 0.1, 0.3, 0.9, 1.0])
    walls = contender("sidewall_friction", 107.5, [0.9, 0.95, 1.1, 1.0, 1.05])
    base = contender("base", 300.0, [2.5, 2.5, 2.0, 1.9, 1.8])
    # by combined score (fit and law), not by fit alone: side-wall friction first
    assert contender_pairs("auto", [base, cohesive, walls]) == [["sidewall_friction", "cohesion"]]
    assert contender_pairs("auto", [base, walls]) == []  # one candidate: nothing to pair
    given = [["rolling_resistance", "sidewall_friction"]]
    assert contender_pairs(given, [base, cohesive, walls]) == given
    for bad, why in (([["cohesion", "cohesion"]], "each mechanism once"), ([["cohesion", "magic"]], "magic")):
        with pytest.raises(CalibrationError, match=rf"calibration.contender_pairs\[0\]: .*{why}"):
            contender_pairs(bad, [base, cohesive, walls])


def test_a_pair_is_physical_only_where_both_its_values_are_and_can_be_chosen():
    pair = model_named("sidewall_friction+rolling_resistance")
    assert pair.parameter_names == ("friction", "restitution", "sidewall_friction", "rolling_friction")
    walls = contender("sidewall_friction", 107.5, [0.9, 0.95, 1.1, 1.0, 1.05])
    # from its member's fit, the other mechanism off
    start = pair.embed(model_named("sidewall_friction"), list(walls.parameters.values()))
    assert start.tolist() == [0.5, 0.6, 0.15, 0.0]
    each, heights = [[f * law for f, law in zip([1.0] * len(A), LAW)]], [[1.0] * len(A)]
    inside = dict(zip(pair.parameter_names, [0.5, 0.6, 0.2, 0.1]))
    outside = dict(inside, rolling_friction=0.38)  # beyond rolling resistance's physical 0.3
    on_law = score_contender(pair, inside, 109.0, A, each, heights, 0.25)
    assert on_law.physical and on_law.plausibility.count("physical range") == 2
    effective = score_contender(pair, outside, 109.0, A, each, heights, 0.25)
    assert not effective.physical and "rolling_friction = 0.38 lies outside" in effective.plausibility
    # on the law with a fit 1.5 worse: the pair beats its member where that one misses the law at a = 0.5 ...
    short = contender("sidewall_friction", 107.5, [0.3, 0.9, 1.0, 1.0, 1.0])
    assert choose([contender("base", 300.0, [2.5] * len(A)), short, on_law]) == (pair.name, "sidewall_friction")
    # ... unless its fit leaves one mechanism off: it is then its member at another point, not a pair
    off = score_contender(pair, dict(inside, rolling_friction=0.001), 109.0, A, each, heights, 0.25)
    assert off.switched_off == ["rolling_resistance"] and on_law.switched_off == []
    assert choose([contender("base", 300.0, [2.5] * len(A)), short, off])[0] == "sidewall_friction"
    # ... and not where the member follows the law too: its extra parameter then buys nothing
    assert choose([contender("base", 300.0, [2.5] * len(A)), walls, on_law])[0] == "sidewall_friction"
    with pytest.raises(MechanismError, match="each mechanism once"):
        Model(*get_mechanisms(["cohesion", "cohesion"]))
    with pytest.raises(MechanismError, match="holds 2 mechanisms, not one"):
        _ = pair.mechanism


def test_the_move_with_grain_size_is_debiased_by_the_packing_scatter_and_weighs_on_the_choice():
    rng = np.random.default_rng(0)
    # two sets of 4 packings about the same curve: the move is their scatter alone, about 0 once debiased
    curve = np.linspace(0.2, 2.0, 7)
    same = debiased_squares(curve + 0.1 * rng.standard_normal((4, 7)), curve + 0.1 * rng.standard_normal((4, 7)))
    raw = 0.1**2 * (1 / 4 + 1 / 4)  # what the squared difference of two such means averages
    assert np.mean(same) < 0.5 * raw
    # moved by 0.3 at every time: 0.09 comes back, less at most the scatter; one run each: not debiased
    moved = debiased_squares(np.array([curve, curve + 0.01]), np.array([curve + 0.3, curve + 0.31]))
    assert moved == pytest.approx(np.full(7, 0.09), abs=1e-3)
    assert debiased_squares(curve[None], curve[None] + 0.2) == pytest.approx(np.full(7, 0.04))
    # two candidates that fit and follow the law alike: the one whose curve moves with the grains loses
    still, moving = (contender(n, 100.0, [1.0] * len(A)) for n in ("sidewall_friction", "rolling_resistance"))
    for c, chi2 in ((still, 0.5), (moving, 12.0)):
        c.grain_shift = GrainShift((5.0, 3.0), [5001, 5002], [1.0] * 7, [1.1] * 7, chi2 / 100, chi2, 10.0)
    assert moving.combined == pytest.approx(100.0 + moving.law_chi2 + 12.0)
    base = contender("base", 300.0, [2.5] * len(A))
    assert choose([base, moving, still])[0] == "sidewall_friction"
    trio = [base, moving, still]
    choice = ContenderChoice("q", trio, "sidewall_friction", "rolling_resistance", 0.25, "law", [1], 1.0)
    again = ContenderChoice.from_dict(json.loads(json.dumps(choice.to_dict())))
    assert again.contender("rolling_resistance").grain_shift == moving.grain_shift
    assert "move from size_scale 5 to 3" in choice.why and "+ transfer 12.0" in choice.why
