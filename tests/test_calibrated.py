"""The calibrated model (calibration/calibrated.py, pipeline/calibrated.py): which model, its
parameters, and the validation on several packings, on tiny coarse-grained columns (77 grains)."""

from types import SimpleNamespace

import numpy as np
import pytest

from calibration.calibrated import CalibrationError, model_runout, resolve_model, validate
from calibration.design_runs import Model, SimulationSettings
from calibration.measured import MeasuredColumn
from calibration.mechanisms import get_mechanisms
from calibration.objective import runout_mse
from dem.engines.liggghts import LiggghtsEngine
from dem.runout import RunoutMethod
from pipeline.calibrated import run_calibrated, run_section
from pipeline.config import ConfigError, check_calibration

RUNOUT = RunoutMethod()
SETTINGS = SimulationSettings(size_scale=4.0)
COLUMN = MeasuredColumn(
    name="tiny",
    material="quartz",
    aspect_ratio=2.0,
    L_i=0.01,
    t_over_tstar=np.array([0.5, 1.0, 1.5, 2.0]),
    runout=np.array([0.2, 0.8, 1.5, 1.9]),
    source="test",
)


def diagnosis(cause, best="cohesion", checks=None):
    return SimpleNamespace(cause=cause, best_candidate=best, checks=checks or {"bic_beats_base": True}, verdict="...")


def test_the_model_is_the_configs_or_the_diagnosis_answer():
    assert resolve_model("base", None)[0] == Model()
    assert resolve_model("sidewall_friction", None)[0].name == "sidewall_friction"
    model, why = resolve_model("auto", diagnosis("cohesion"))
    assert model.name == "cohesion" and "the diagnosis named cohesion" in why
    model, why = resolve_model(
        "auto", diagnosis("none", "rolling_resistance", {"a": True, "bic_beats_runner_up": False})
    )
    assert model.name == "rolling_resistance" and "named no cause (bic_beats_runner_up failed)" in why
    with pytest.raises(CalibrationError, match="auto needs the diagnosis"):
        resolve_model("auto", None)
    with pytest.raises(CalibrationError, match="unknown model 'friction'"):
        resolve_model("friction", None)


def test_validation_scores_the_mean_curve_of_its_packings():
    """Known answer: the mean of the packings' own runout curves, and its MSE, computed here again."""
    theta = (0.5, 0.6)
    result = validate("base", Model(), COLUMN, theta, SETTINGS, RUNOUT, None, n_packings=2)
    curves = [model_runout(Model(), COLUMN, theta, SETTINGS, seed, RUNOUT, None) for seed in result.seeds]
    np.testing.assert_allclose(result.mean, np.mean(curves, axis=0))
    np.testing.assert_allclose(result.std, np.std(curves, axis=0, ddof=1))
    assert result.mse == pytest.approx(runout_mse(np.mean(curves, axis=0), COLUMN.runout))
    assert result.mse_each == pytest.approx([runout_mse(c, COLUMN.runout) for c in curves])
    assert not np.allclose(curves[0], curves[1])  # two packings, two collapses
    assert result.failed == {} and result.n_ran == 2


def test_a_run_that_fails_is_reported_with_its_packing_never_averaged():
    """LIGGGHTS does not model cohesion: every run is refused by the engine (or, where LIGGGHTS is
    not installed, the engine cannot start), reported with its packing, and the score is NaN."""
    model = Model(get_mechanisms(["cohesion"])[0])
    config = {"engine": "liggghts"}
    result = validate("cohesion", model, COLUMN, (0.5, 0.6, 10.0), SETTINGS, RUNOUT, config, n_packings=2)
    assert result.n_ran == 0 and np.isnan(result.mse) and set(result.failed) == set(result.seeds)
    assert np.isnan(result.mean).all() and np.isnan(result.mse_each).all()
    installed, _ = LiggghtsEngine().availability()
    expected = "does not model cohesion_energy" if installed else "EngineNotInstalled"
    assert all(expected in why for why in result.failed.values()), result.failed


def test_the_stage_writes_its_answer_figure_and_report_section(tmp_path):
    csv = tmp_path / "tiny.csv"
    csv.write_text(
        "column,material,aspect_ratio,L_i,kind,x,value,std\n"
        + "".join(f"tiny,quartz,2,0.01,runout,{t},{v},\n" for t, v in zip(COLUMN.t_over_tstar, COLUMN.runout))
    )
    section = {"model": "base", "budget": 4, "n_initial": 2, "validation_packings": 2, "seed": 0}
    section.update(finer_size_scale=3.5, predict_aspect_ratios=[1.0, 2.0])
    out = tmp_path / "calibrated"
    result = run_calibrated(
        csv, None, out / "calibrated.json", out / "calibrated.png", out / "prediction.png", section,
        {"size_scale": 4.0, "channel_width": 0.01}, runout=RUNOUT.to_config(), dem=None, name="tiny",
    )  # fmt: skip
    assert result["model"] == "base" and result["answer"] == "base, BO on DEM"
    (route,) = result["routes"]
    assert route["dem_runs"] == 4 and len(route["extra"]["history"]["values"]) == 4
    assert route["mse"] == pytest.approx(runout_mse(np.array(route["mean"]), COLUMN.runout))
    assert (out / "calibrated.png").stat().st_size > 10_000 and (out / "prediction.png").stat().st_size > 10_000
    transfer = result["transfer"]  # the answer again, grains 4 / 3.5 times finer: more grains, other curves
    assert transfer["parameters"] == route["parameters"] and transfer["mean"] != route["mean"]
    prediction = result["prediction"]
    assert prediction["aspect_ratios"] == [1.0, 2.0] and prediction["failed"] == {}
    assert 0 < prediction["final_runout"][0] < prediction["final_runout"][1]  # taller columns run further
    assert prediction["height_over_L_i"][0] < prediction["height_over_L_i"][1]
    run_section([out / "calibrated.json"], [out / "calibrated.png"], tmp_path / "report" / "calibrated.md")
    text = (tmp_path / "report" / "calibrated.md").read_text()
    assert "### tiny: base model" in text and "](../calibrated/calibrated.png)" in text
    assert f"validated runout MSE **{route['mse']:.3g}**" in text and "**Scale transfer.**" in text
    assert "| final L* | " in text and "](../calibrated/prediction.png)" in text


def config_with(model, engine="builtin", diagnosis_enabled=True):
    return {
        "calibration": {"enabled": True, "model": model},
        "measured": {"quartz": "data/measured/quartz_a6.csv"},
        "diagnosis": {
            "enabled": diagnosis_enabled,
            "candidates": ["rolling_resistance", "cohesion"],
            "channel_width": 0.01,
        },
        "dem": {"engine": engine, "solvers": {}},
    }


def test_a_model_the_engine_cannot_run_is_refused_before_any_job():
    check_calibration(config_with("cohesion"))  # the builtin engine runs every mechanism
    check_calibration(config_with("rolling_resistance", "liggghts"))  # LIGGGHTS runs rolling resistance
    with pytest.raises(ConfigError, match=r"calibration.model: cohesion .*\['cohesion'\].*liggghts cannot run"):
        check_calibration(config_with("cohesion", "liggghts"))
    with pytest.raises(ConfigError, match=r"auto calibrates the diagnosis candidates \['cohesion'\]"):
        check_calibration(config_with("auto", "liggghts"))
    with pytest.raises(ConfigError, match="auto takes the diagnosis' answer, but diagnosis.enabled is false"):
        check_calibration(config_with("auto", diagnosis_enabled=False))


def test_the_papers_base_routes_are_read_for_validation_beside_the_model(tmp_path):
    """The optima of the GNS inverse design, the DoE fits and the base BO, as their stages write them."""
    import json

    from pipeline.calibrated import base_route_optima

    (tmp_path / "inverse.json").write_text(
        json.dumps({"names": ["restitution", "friction"], "best_params": [0.4, 0.7]})
    )
    optimum = {"natural": {"friction": 0.9, "restitution": 0.3}}
    doe = {"n_runs": 50, "models": {"eq9": {"optimum": optimum}, "quadratic": {"optimum": optimum}}}
    (tmp_path / "analysis.json").write_text(json.dumps(doe))
    bo = {"names": ["friction", "restitution"], "best_params": [0.8, 0.5], "values": [1.0] * 20}
    (tmp_path / "bayesopt.json").write_text(json.dumps(bo))
    files = {
        k: tmp_path / f
        for k, f in (("inverse", "inverse.json"), ("doe", "analysis.json"), ("bayesopt", "bayesopt.json"))
    }
    assert base_route_optima(files) == [
        ("base, GNS inverse design", [0.7, 0.4], 0),  # in (mu, e) order whatever the file's order
        ("base, DoE (eq9)", [0.9, 0.3], 50),
        ("base, DoE (quadratic)", [0.9, 0.3], 50),
        ("base, BO on DEM", [0.8, 0.5], 20),
    ]
    assert base_route_optima({}) == []
