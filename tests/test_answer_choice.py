"""The choice of the calibrated answer (calibration/answer_choice.py) and the calibrated.json it is
written to (calibration/calibrated_result.py): the routes not told apart from the best, the lowest
validated route without a runoff, the GNS route against each DoE route, the record's round trip."""

import math

import numpy as np
import pytest

from calibration.answer_choice import choose_answer, contenders, gns_versus_doe
from calibration.calibrated import CalibrationError, mse_jackknife
from calibration.calibrated_result import CalibratedResult
from dem.atomic import write_json
from tests.test_calibrated import COLUMN, RUNOUT  # the tiny measured column of the calibrated stage


def calibrated_record():
    """A calibrated.json as run_calibrated writes it (keys in its order), small: one route, which
    failed on one packing (a None curve, a NaN MSE), its runoff, no diagnosis and no GNS route."""
    route = {
        "route": "base, BO on DEM", "parameters": {"friction": 0.5, "restitution": 0.6}, "seeds": [5001, 5002],
        "t_over_tstar": [0.5, 1.0], "curves": [[0.2, 0.7], None], "failed": {"5002": "blew up"},
        "mean": [0.2, 0.7], "std": [float("nan"), float("nan")], "mse": 0.01, "mse_each": [0.01, float("nan")],
        "seconds": 3.5, "dem_runs": 4, "calibration_seconds": 12.0, "extra": {}, "mse_se": None,
        "key": "model-bayesopt", "model": "base", "versus_answer": {"mse_difference": 0.0, "se": None},
    }  # fmt: skip
    shown = ("key", "route", "parameters", "seeds", "curves", "failed", "mse", "mse_se", "mse_each")
    runoff = {key: route[key] for key in shown} | {"shared_packings": 2}
    prediction = {
        "aspect_ratios": [1.0, 2.0], "final_runout": [0.9, None], "final_height": [0.004, None],
        "height_over_L_i": [0.4, None], "failed": {"2": "blew up"}, "seed": 5001, "seconds": 2.0,
    }  # fmt: skip
    return {
        "name": "tiny", "measured": "tiny.csv", "column": "tiny", "model": "base",
        "parameters": ["friction", "restitution"], "bounds": [[0.3, 0.9], [0.3, 0.9]], "why": "the config",
        "plausible": None, "answer": "base, BO on DEM", "routes": [route], "runoff": [runoff],
        "answer_packings": 3, "intervals": None, "gns_intervals": None, "gns_sensitivity": None, "gns_vs_doe": [],
        "target": None, "transfer": None, "prediction": prediction, "prediction_size_scale": 4.0,
        "measured_final_runout": 1.9, "prediction_measured_a": 2.0,
        "size_scale": 4.0, "engine": "builtin", "runout": RUNOUT.to_config(), "runout_stated": False,
        "validation_packings": 2, "calibration_packing": 0, "seconds": 41.0,
    }  # fmt: skip


def test_the_calibrated_record_round_trips_its_file_and_refuses_other_keys(tmp_path):
    """calibrated.json read into a CalibratedResult and written again is the same bytes (NaN, None
    and the keys' order included); a file with a key missing or one it does not know is refused,
    naming the file and the key."""
    record = calibrated_record()
    write_json(tmp_path / "calibrated.json", record)  # what run_calibrated wrote before it had a class
    result = CalibratedResult.from_json(tmp_path / "calibrated.json")
    assert list(result.to_dict()) == list(record) and result.answer_packings == 3 and result.transfer is None
    result.to_json(tmp_path / "again.json")
    assert (tmp_path / "again.json").read_bytes() == (tmp_path / "calibrated.json").read_bytes()
    without = {k: v for k, v in record.items() if k != "transfer"}
    write_json(tmp_path / "old.json", without)
    with pytest.raises(CalibrationError, match=r"old\.json: no key 'transfer'"):
        CalibratedResult.from_json(tmp_path / "old.json")
    write_json(tmp_path / "new.json", dict(record, figure="calibrated.png"))
    with pytest.raises(CalibrationError, match=r"new\.json: unknown key 'figure'"):
        CalibratedResult.from_json(tmp_path / "new.json")
    (tmp_path / "list.json").write_text("[]")
    with pytest.raises(CalibrationError, match=r"list\.json: not a calibrated record"):
        CalibratedResult.from_json(tmp_path / "list.json")


def test_the_routes_not_told_apart_from_the_best_are_the_contenders():
    rng = np.random.default_rng(3)
    chaos = rng.normal(0, 0.3, (6, 4))  # one packing's scatter, shared by every route on that packing

    def route(name, offset, own=0.05):
        curves = COLUMN.runout + offset + chaos + rng.normal(0, own, (6, 4))
        return {"route": name, "curves": curves.tolist()}

    best, close, far = route("best", 0.0), route("close", 0.05), route("far", 1.0)
    measured = COLUMN.runout
    difference, se = mse_jackknife(far["curves"], measured, best["curves"])
    assert difference > 2 * se  # told apart; close's difference (either sign) is within the scatter
    assert [r["route"] for r in contenders([far, close, best], measured, best)] == ["best", "close"]
    assert contenders([best], measured, best) == [best]
    failed = {"route": "failed everywhere", "curves": [None] * 6}  # no score: no contender
    assert [r["route"] for r in contenders([best, failed, close], measured, best)] == ["best", "close"]
    # two packings give no standard error: nothing is told apart
    two = [{"route": r["route"], "curves": r["curves"][:2]} for r in (best, far)]
    assert len(contenders(two, measured, two[0])) == 2


def test_without_a_runoff_the_answer_is_the_lowest_validated_route_and_the_gns_is_held_against_each_doe():
    """No runoff (answer_packings not above the validation's): the lowest finite MSE answers, a route
    whose runs all failed (NaN) never; the GNS route against each DoE route, GNS minus DoE."""
    rng = np.random.default_rng(5)
    chaos = rng.normal(0, 0.1, (4, 4))

    def route(key, offset, mse, runs):
        curves = (COLUMN.runout + offset + chaos).tolist()
        return {"key": key, "route": key, "curves": curves, "mse": mse, "dem_runs": runs}

    gns, doe, failed = (
        route("model-inverse", 0.4, 0.2, 36),
        route("model-doe-ff", 0.0, 0.01, 50),
        route("x", 0, math.nan, 9),
    )
    answer, scored = choose_answer([gns, failed, doe], None, COLUMN, None, None, None, 4, 4)
    assert answer is doe and scored == []
    (versus,) = gns_versus_doe([gns, failed, doe], scored, COLUMN.runout)
    assert versus["doe_key"] == "model-doe-ff" and versus["packings"] == 4
    assert versus["mse_difference"] > 0 and versus["gns_dem_runs"] == 36 and versus["doe_dem_runs"] == 50
    assert gns_versus_doe([failed, doe], [], COLUMN.runout) == []  # no GNS route
