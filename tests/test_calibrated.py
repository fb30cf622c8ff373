"""The calibrated model (calibration/calibrated.py, pipeline/calibrated.py): which model, its
parameters, and the validation on several packings, on tiny coarse-grained columns (77 grains)."""

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from calibration.calibrated import (
    CalibrationError,
    calibration_box,
    model_dataset_cases,
    model_record,
    model_runout,
    mse_jackknife,
    read_model,
    resolve_model,
    validate,
)
from calibration.calibrated_result import CalibratedResult
from calibration.design_runs import SimulationSettings
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import bond_from_cohesion_energy, get_mechanisms
from calibration.model import Model
from calibration.objective import runout_mse
from calibration.scaling_laws import check_scaling
from dem.atomic import write_json
from dem.case import get_material
from dem.engines.liggghts import LiggghtsEngine
from dem.runout import RunoutMethod
from pipeline.calibrated import choose_model, run_calibrated, run_model_bayesopt, run_validation
from pipeline.calibrated_column import CalibratedColumn
from pipeline.calibrated_doe import run_model_doe
from pipeline.calibrated_section import run_section, transfer_holds
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
    fractions = []  # the job's progress: the share of all its runs done, rising to 1
    result = validate("base", Model(), COLUMN, theta, SETTINGS, RUNOUT, None, n_packings=2, progress=fractions.append)
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    assert any(0.4 < f <= 0.5 for f in fractions) and np.max(np.diff([0.0, *fractions])) <= 0.1 + 1e-9
    curves = [model_runout(Model(), COLUMN, theta, SETTINGS, seed, RUNOUT, None) for seed in result.seeds]
    np.testing.assert_allclose(result.mean, np.mean(curves, axis=0))
    np.testing.assert_allclose(result.std, np.std(curves, axis=0, ddof=1))
    assert result.mse == pytest.approx(runout_mse(np.mean(curves, axis=0), COLUMN.runout))
    assert result.mse_each == pytest.approx([runout_mse(c, COLUMN.runout) for c in curves])
    assert not np.allclose(curves[0], curves[1])  # two packings, two collapses
    assert result.failed == {} and result.n_ran == 2


def test_the_jackknife_error_of_a_validation_is_the_textbook_one_and_a_paired_difference_cancels_shared_chaos():
    measured = np.zeros(2)
    # MSE of the mean of curves (x, x): x^2; leave-one-out means of [0, 1, 2, 3] by hand
    curves = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]
    loo = np.array([2.0, 5 / 3, 4 / 3, 1.0]) ** 2
    expected = np.sqrt(3 / 4 * np.sum((loo - loo.mean()) ** 2))
    value, se = mse_jackknife(curves, measured)
    assert value == pytest.approx(1.5**2) and se == pytest.approx(expected)
    # a failed packing is left out, of both routes in a paired difference
    assert mse_jackknife([*curves, None], measured) == pytest.approx((value, se))
    # a route that differs from another by a constant on every packing: the shared scatter cancels
    # in the paired difference, which is then known far better than either score
    shifted = [[c[0] + 0.5, c[1] + 0.5] for c in curves]
    difference, paired_se = mse_jackknife(shifted, measured, curves)
    assert difference == pytest.approx(2.0**2 - 1.5**2)
    assert paired_se < mse_jackknife(shifted, measured)[1]
    assert mse_jackknife(curves[:2], measured)[1] is None  # two packings: no error estimate (JSON null)


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
    section = {"model": "base", "budget": 4, "n_initial": 2, "validation_packings": 2, "answer_packings": 3, "seed": 0}
    section.update(finer_size_scale=3.5, predict_aspect_ratios=[1.0, 2.0])
    out = tmp_path / "calibrated"
    record = choose_model(None, out / "model.json", "base", 0.01, name="tiny")
    assert record["model"] == "base" and record["parameters"] == ["friction", "restitution"]
    diagnosis_section = {"size_scale": 4.0, "channel_width": 0.01}
    job = CalibratedColumn.read(
        csv, out / "model.json", diagnosis_section, runout=RUNOUT.to_config(), dem=None, name="tiny"
    )
    bo = run_model_bayesopt(job, out / "bayesopt.json", out / "bayesopt.png", section)
    assert (out / "bayesopt.png").stat().st_size > 10_000
    assert bo["dem_runs"] == 4 and bo["value"] == min(bo["history"]["values"])
    validation = run_validation(job, "model-bayesopt", out / "bayesopt.json", out / "validation.json", section)
    assert (
        validation["key"] == "model-bayesopt" and validation["model"] == "base" and validation["seeds"] == [5001, 5002]
    )
    # the DoE route (a 3 x 3 face-centred design + 1 centre replicate) beside it
    doe_files = out / "doe.json", out / "doe_responses.csv", out / "doe_surface.png"
    run_model_doe(job, *doe_files, {"doe_centre_replicates": 1})
    doe = run_validation(job, "model-doe", out / "doe.json", out / "validation_doe.json", section)
    assert doe["dem_runs"] == 10 and 0 <= doe["extra"]["r_squared"] <= 1
    result = run_calibrated(
        job, [out / "validation.json", out / "validation_doe.json"], None,
        out / "calibrated.json", out / "calibrated.png", out / "prediction.png", section,
    )  # fmt: skip
    assert result.model == "base" and [r["key"] for r in result.routes] == ["model-bayesopt", "model-doe"]
    # the file is the record: read back and written again, the same bytes
    CalibratedResult.from_json(out / "calibrated.json").to_json(tmp_path / "again.json")
    assert (tmp_path / "again.json").read_bytes() == (out / "calibrated.json").read_bytes()
    # the runoff: two packings give no SE, so neither route is told apart: both run on a third
    scored = {r["key"]: r for r in result.runoff}
    assert set(scored) == {"model-bayesopt", "model-doe"} and result.answer_packings == 3
    for r in result.routes:
        more = scored[r["key"]]
        assert more["seeds"] == [5001, 5002, 5003] and more["curves"][:2] == r["curves"]
        assert more["shared_packings"] == 2 and more["parameters"] == r["parameters"]
        assert more["mse"] == pytest.approx(runout_mse(np.mean(more["curves"], axis=0), COLUMN.runout))
    assert result.answer == min(result.runoff, key=lambda r: r["mse"])["route"]
    route = next(r for r in result.routes if r["route"] == result.answer)
    bo_route = result.routes[0]
    assert bo_route["parameters"] == bo["optimum"]
    assert bo_route["dem_runs"] == 4 and len(bo_route["extra"]["history"]["values"]) == 4
    assert route["mse"] == pytest.approx(runout_mse(np.array(route["mean"]), COLUMN.runout))
    assert (out / "calibrated.png").stat().st_size > 10_000 and (out / "prediction.png").stat().st_size > 10_000
    transfer = result.transfer  # the answer again, grains 4 / 3.5 times finer: more grains, other curves
    assert transfer["parameters"] == route["parameters"] and transfer["mean"] != route["mean"]
    prediction = result.prediction
    assert prediction["aspect_ratios"] == [1.0, 2.0] and prediction["failed"] == {}
    assert 0 < prediction["final_runout"][0] < prediction["final_runout"][1]  # taller columns run further
    # a deposit's top is read off one packing's grains (here 0.17 L_i across, about 6 grains to L_i): the taller
    # column's deposit is the taller one only to within a grain (one AMD EPYC run: 0.650 L_i at a = 1 against
    # 0.641 at a = 2, both answers' parameters drawn by a machine-dependent BO and DoE), and each column has
    # fallen below its initial height a L_i
    grain = get_material(COLUMN.material).diameter * SETTINGS.size_scale / COLUMN.L_i
    height = prediction["height_over_L_i"]
    assert height[0] < height[1] + grain and all(0 < h < a for h, a in zip(height, prediction["aspect_ratios"]))
    run_section([out / "calibrated.json"], [out / "calibrated.png"], tmp_path / "report" / "calibrated.md")
    text = (tmp_path / "report" / "calibrated.md").read_text()
    assert "### tiny: base model" in text and "](../calibrated/calibrated.png)" in text
    assert f"validated runout MSE **{scored[route['key']]['mse']:.3g}**" in text and "**Scale transfer.**" in text
    # the finer scale is set against the answer on as many packings (its validation's), not the runoff's
    assert f"against {route['mse']:.3g} at size_scale 4 on as many packings" in text
    assert transfer_holds({"mse": 0.15}, 0.1) and not transfer_holds({"mse": 0.25}, 0.1)
    assert result.target is None and result.prediction_size_scale == 4  # no target: the calibration's scale
    assert "How the answer was chosen" in text and "on the mean of 3 packings" in text
    assert "| final L* | " in text and "](../calibrated/prediction.png)" in text
    # the predictions held against the channel law, as a fraction of it per a and in one figure
    check = check_scaling(prediction["aspect_ratios"], prediction["final_runout"], prediction["height_over_L_i"])
    fractions = " | ".join(f"{v:.2f}" for v in check.runout_fraction())
    assert f"| fraction of that law | {fractions} |" in text and "**Scaling check**" in text
    assert f"off by a factor of {math.exp(check.runout_error):.2g} on average" in text
    assert (
        "base, DoE (face-centred CCD, quadratic): 10 DEM runs (every DEM run ran); quadratic response surface" in text
    )
    assert "](../calibrated/doe_surface.png)" in text and "](../calibrated/bayesopt.png)" in text


def config_with(model, engine="builtin", diagnosis_enabled=True):
    return {
        "calibration": {
            "enabled": True,
            "model": model,
            "gns_optimiser": "bayesopt",
            "gns_budget": 40,
            "gns_n_initial": 12,
            "gns_warm_start": False,
            "gns_latent_size": 48,
            "gns_learning_rate_decay_steps": None,
        },
        "gns": {"latent_size": 32},
        "measured": {"quartz": "data/measured/quartz_a6.csv"},
        "diagnosis": {
            "enabled": diagnosis_enabled,
            "candidates": ["rolling_resistance", "cohesion"],
            "channel_width": 0.01,
            "size_scale": 5.0,
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
    # a pair: each of its mechanisms must run on the engine, and a mechanism pairs with another
    check_calibration(config_with("rolling_resistance+sidewall_friction"))
    with pytest.raises(ConfigError, match=r"rolling_resistance\+cohesion .*\['cohesion'\].*liggghts cannot run"):
        check_calibration(config_with("rolling_resistance+cohesion", "liggghts"))
    with pytest.raises(ConfigError, match="calibration.model: cohesion.cohesion pairs cohesion with itself"):
        check_calibration(config_with("cohesion+cohesion"))
    paired = config_with("auto")
    paired["calibration"]["contender_pairs"] = [["rolling_resistance", "rolling_resistance"]]
    with pytest.raises(ConfigError, match=r"calibration.contender_pairs\[0\]: .* pairs rolling_resistance with itself"):
        check_calibration(paired)
    paired["calibration"]["contender_pairs"] = [["rolling_resistance", "cohesion"]]  # cohesion: not in LIGGGHTS
    paired["diagnosis"]["candidates"], paired["dem"]["engine"] = ["rolling_resistance"], "liggghts"
    paired["calibration"]["contender_pairs"] = []
    check_calibration(paired)  # the candidate alone runs there ...
    paired["calibration"]["contender_pairs"] = [["rolling_resistance", "cohesion"]]
    with pytest.raises(ConfigError, match=r"candidates and contender pairs \[.cohesion.\]"):
        check_calibration(paired)  # ... its pair with cohesion does not
    short = config_with("cohesion")
    short["calibration"]["gns_budget"] = 10
    with pytest.raises(ConfigError, match=r"calibration.gns_budget: 10 GNS points cannot hold the 12 of the initial"):
        check_calibration(short)
    warm = config_with("cohesion")
    warm["calibration"]["gns_warm_start"] = True  # a warm start keeps the base GNS's width
    with pytest.raises(ConfigError, match=r"calibration.gns_latent_size: 48, but .* 32 wide .*set it to null or 32"):
        check_calibration(warm)
    # the width of the base GNS of the column, gns.per_dataset included
    warm["gns"]["per_dataset"] = {"quartz_multiple": {"latent_size": 48}}
    check_calibration(warm, {"quartz": "quartz_multiple"})
    with pytest.raises(ConfigError, match=r"from the base GNS of other, 32 wide"):
        check_calibration(warm, {"quartz": "other"})
    warm["calibration"]["gns_latent_size"] = None
    check_calibration(warm)
    warm["calibration"]["gns_learning_rate_decay_steps"] = 12000  # a warm start keeps the base's schedule
    with pytest.raises(ConfigError, match=r"gns_learning_rate_decay_steps: sets the schedule .*from scratch"):
        check_calibration(warm)


def test_every_routes_optimum_is_read_as_its_stage_writes_it(tmp_path):
    """The optima of the paper's GNS inverse design, DoE fits and base BO, and of the model's own
    GNS inverse design, in each model's parameter order whatever the file's."""
    import json

    from pipeline.calibrated import route_optimum

    model = Model(get_mechanisms(["cohesion"])[0])
    posterior = {"parameters": [{"name": "bond_number", "low": 40.0, "high": 48.0}]}
    files = {
        "inverse.json": {"names": ["restitution", "friction"], "best_params": [0.4, 0.7]},
        "analysis.json": {"n_runs": 50, "models": {"eq9": {"optimum": {"natural": {"friction": 0.9, "restitution": 0.3}}}}},  # noqa: E501
        # 19 runs ran, one failed: the runs it cost are the file's dem_runs
        "bayesopt.json": {"names": ["friction", "restitution"], "best_params": [0.8, 0.5], "values": [1.0] * 19}
        | {"dem_runs": 20},
        "model_inverse.json": {
            "names": ["bond_number", "friction", "restitution"], "best_params": [44.0, 0.5, 0.6],
            "best_value": 0.05, "posterior": posterior,
        },
    }  # fmt: skip
    for name, data in files.items():
        (tmp_path / name).write_text(json.dumps(data))
    read = lambda key, name: route_optimum(key, tmp_path / name, model)  # noqa: E731
    assert read("base-inverse", "inverse.json") == ("base, GNS inverse design", Model(), [0.7, 0.4], 0, 0.0, {})
    assert read("base-doe-eq9", "analysis.json") == ("base, DoE (eq9)", Model(), [0.9, 0.3], 50, 0.0, {})
    assert read("base-bayesopt", "bayesopt.json") == ("base, BO on DEM", Model(), [0.8, 0.5], 20, 0.0, {})
    label, route_model, theta, _, _, extra = read("model-inverse", "model_inverse.json")
    assert (label, route_model, theta) == ("cohesion, GNS inverse design", model, [0.5, 0.6, 44.0])
    assert extra["intervals"] == posterior["parameters"] and extra["gns_objective"] == 0.05
    with pytest.raises(CalibrationError, match="unknown calibration route 'base-magic'"):
        read("base-magic", "inverse.json")


def test_the_model_file_names_the_model_and_refuses_what_is_not_one(tmp_path):
    """model.json is what every job of the stage reads: auto resolved once, by the diagnosis."""
    model, why = resolve_model("auto", diagnosis("cohesion"))
    write_json(tmp_path / "model.json", model_record(model, why, "quartz"))
    assert read_model(tmp_path / "model.json") == (model, why)
    (tmp_path / "junk.json").write_text("{}")
    with pytest.raises(CalibrationError, match="junk.json: not a calibrated-model file"):
        read_model(tmp_path / "junk.json")
    write_json(tmp_path / "other.json", dict(model_record(model, why), parameters=["friction", "restitution"]))
    with pytest.raises(CalibrationError, match="differ from model cohesion's"):
        read_model(tmp_path / "other.json")
    # the mechanism's plausible range for the column's material travels with the model
    csv = tmp_path / "glass.csv"
    csv.write_text("column,material,aspect_ratio,L_i,kind,x,value,std\n" + "".join(
        f"glass,quartz,2,0.01,runout,{t},{v},\n" for t, v in zip(COLUMN.t_over_tstar, COLUMN.runout)
    ))  # fmt: skip
    ranges = {"quartz": {"cohesion": {"range": [0.0, 5.0], "source": "our shear cell"}}}
    record = choose_model(None, tmp_path / "stated.json", "cohesion", 0.01, measured_path=csv, plausible_ranges=ranges)
    assert record["plausible"] == [[0.0, 5.0]] and record["plausible_source"] == ["our shear cell"]
    stated, _ = read_model(tmp_path / "stated.json")
    assert stated.mechanism.plausible == (0.0, 5.0) and "effective" not in stated.mechanism.plausibility(4.0)
    assert read_model(tmp_path / "model.json")[0].mechanism.plausible == (0.0, 1.0)  # the built-in
    # a pair of mechanisms: named by the config, each parameter with its own box and plausible range
    record = choose_model(None, tmp_path / "pair.json", "sidewall_friction+cohesion", 0.01, measured_path=csv,
                          plausible_ranges=ranges)  # fmt: skip
    pair, why = read_model(tmp_path / "pair.json")
    assert pair.name == "sidewall_friction+cohesion" and "sidewall_friction + cohesion" in why
    assert pair.parameter_names == ("friction", "restitution", "sidewall_friction", "bond_number")
    assert [m.plausible for m in pair.mechanisms] == [(0.1, 0.6), (0.0, 5.0)]
    assert pair.at(COLUMN.collapse_case(0.5, 0.5, size_scale=4.0), [0.4, 0.5, 0.2, 3.0]).sidewall_friction == 0.2
    with pytest.raises(CalibrationError, match=r"unknown model 'cohesion\+magic'.*unknown candidate"):
        resolve_model("cohesion+magic", None)
    with pytest.raises(CalibrationError, match="pair.json: plausible ranges .* not one per mechanism"):
        write_json(tmp_path / "pair.json", dict(record, plausible=[[0.1, 0.6]]))
        read_model(tmp_path / "pair.json")


def test_the_models_gns_dataset_varies_every_parameter_on_its_own_packings():
    """A Latin hypercube over the model's box on the template's column: every parameter spread over
    its range, the mechanism switched on through its own case fields, one packing per case."""
    model = Model(get_mechanisms(["cohesion"])[0])
    template = COLUMN.collapse_case(0.5, 0.5, size_scale=4.0, seed=1, output_interval=0.005, name="tiny/case_000")
    cases = model_dataset_cases(model, template, 10, 0)
    assert [c.case_id for c in cases] == [f"case_{k:03d}" for k in range(10)]
    theta = np.array([[c.parameters[n] for n in model.parameter_names] for c in cases])
    assert list(theta[:, 2]) == sorted(theta[:, 2])  # in the mechanism's order: the splits spread along it
    for j, (low, high) in enumerate(model.bounds):  # one point per tenth of every range (a Latin hypercube)
        assert sorted(np.floor((theta[:, j] - low) / (high - low) * 10).astype(int)) == list(range(10))
    for c in cases:
        assert (c.case.friction, c.case.restitution) == (c.parameters["friction"], c.parameters["restitution"])
        assert bond_from_cohesion_energy(c.case.cohesion_energy, c.case) == pytest.approx(c.parameters["bond_number"])
        assert (c.case.L_i, c.case.output_interval, c.case.size_scale) == (0.01, 0.005, 4.0)
    assert len({c.case.seed for c in cases}) == 10 and template.seed not in {c.case.seed for c in cases}
    with pytest.raises(CalibrationError, match="cannot fill train, valid and test"):
        model_dataset_cases(model, template, 2, 0)


def boxed_diagnosis(estimate, low, high, identifiable=True):
    """A diagnosis whose cohesion fit put the Bond number at `estimate`, 95% in [low, high]."""
    interval = SimpleNamespace(name="bond_number", low=low, high=high, identifiable=identifiable)
    evidence = SimpleNamespace(
        dem=SimpleNamespace(parameters={"friction": 0.5, "restitution": 0.5, "bond_number": estimate}),
        emulator=SimpleNamespace(posterior=SimpleNamespace(parameters=[interval])),
    )
    return SimpleNamespace(candidates={"cohesion": evidence})


def test_the_calibration_box_follows_the_diagnosis_and_stays_in_the_candidates_range(tmp_path):
    """Known answers: 2x the 95% interval around the estimate, at least a quarter of [0, 60], slid
    inside [0, 60]; the whole range when the diagnosis could not pin the parameter down."""
    model = Model(get_mechanisms(["cohesion"])[0])
    box = lambda d, kind="diagnosis": tuple(calibration_box(model, d, kind).mechanism.bounds)  # noqa: E731
    assert box(boxed_diagnosis(44.0, 40.0, 48.0)) == pytest.approx((36.0, 52.0))  # 2 x 8 wide
    assert box(boxed_diagnosis(44.0, 43.0, 45.0)) == pytest.approx((36.5, 51.5))  # at least 15 = 60 / 4
    assert box(boxed_diagnosis(58.0, 55.0, 60.0)) == pytest.approx((45.0, 60.0))  # slid inside
    assert box(boxed_diagnosis(44.0, 20.0, 60.0)) == (0.0, 60.0)  # 80 wide: the whole range
    assert box(boxed_diagnosis(44.0, 40.0, 48.0, identifiable=False)) == (0.0, 60.0)
    assert box(boxed_diagnosis(44.0, 40.0, 48.0), "full") == (0.0, 60.0)
    with pytest.raises(CalibrationError, match="unknown box 'narrow'"):
        box(boxed_diagnosis(44.0, 40.0, 48.0), "narrow")
    # the box travels in model.json; a range outside the candidate's is refused
    boxed = calibration_box(model, boxed_diagnosis(44.0, 40.0, 48.0))
    write_json(tmp_path / "model.json", model_record(boxed, "why"))
    assert read_model(tmp_path / "model.json")[0] == boxed
    write_json(tmp_path / "wide.json", dict(model_record(boxed, "why"), bounds=[[0.3, 0.9], [0.3, 0.9], [30, 70]]))
    with pytest.raises(CalibrationError, match=r"bond_number range \[30, 70\] is not inside its whole range \[0, 60\]"):
        read_model(tmp_path / "wide.json")


def test_the_models_gns_has_the_base_gns_settings_from_scratch_or_as_a_fine_tuning():
    """The base GNS's settings with the model's steps: from scratch, the learning rate falls over
    them; a warm start starts from the base's weights at a lower rate, the schedule compressed."""
    from pipeline.calibrated_gns import case_splits, model_gns_settings

    base = {"latent_size": 32, "steps": 12000, "learning_rate_decay_steps": 10000, "pushforward_fraction": 0.5}
    assert model_gns_settings(base, 18000) == dict(base, steps=18000, learning_rate_decay_steps=18000)
    wider = model_gns_settings(base, 18000, latent_size=48)
    assert wider == dict(base, latent_size=48, steps=18000, learning_rate_decay_steps=18000)
    # stopped early on a longer run's schedule (calibration.gns_learning_rate_decay_steps)
    assert model_gns_settings(base, 9000, decay_steps=12000) == dict(base, steps=9000, learning_rate_decay_steps=12000)
    settings = model_gns_settings(base, 6000, "results/gns/q/train/model_best.pt", 3e-4)
    assert settings == dict(
        base,
        steps=6000,
        learning_rate=3e-4,
        learning_rate_decay_steps=5000,
        init_from="results/gns/q/train/model_best.pt",
    )
    # the dataset's case ids and splits are known before the model is (the DAG's shape)
    rows = case_splits({"gns_cases": 10, "gns_splits": {"train": 0.8, "valid": 0.1, "test": 0.1}})
    assert [r["case_id"] for r in rows] == [f"case_{k:03d}" for k in range(10)]
    splits = [r["split"] for r in rows]
    assert splits.count("test") == 1 and splits.count("valid") == 1 and splits.count("train") == 8
    model = Model(get_mechanisms(["cohesion"])[0])
    template = COLUMN.collapse_case(0.5, 0.5, size_scale=4.0, seed=1, output_interval=0.005, name="tiny/case_000")
    designed = model_dataset_cases(model, template, 10, 0)
    assert [r["case_id"] for r in rows] == [c.case_id for c in designed]


def test_the_bo_figure_draws_a_model_of_three_parameters(tmp_path):
    """The BO runs of the extended model (mu, e, Bond) drawn in the (mu, e) plane, best labelled in full."""
    from calibration.compare import plot_bayesopt

    history = {
        "names": ["friction", "restitution", "bond_number"],
        "params": [[0.5, 0.6, 40.0], [0.7, 0.4, 45.0], [0.8, 0.5, 42.0]],
        "values": [0.5, 0.1, 0.2],
        "best_params": [0.7, 0.4, 45.0],
    }
    plot_bayesopt(history, tmp_path / "bo.png", title="three parameters")
    assert (tmp_path / "bo.png").stat().st_size > 10_000


def test_the_gns_routes_runs_are_split_in_words_only_when_it_borrows_the_base_gns():
    """A model's GNS trained from scratch spends only its own dataset's runs; a warm-started one also
    the base GNS's, and the report says which part is whose."""
    from pipeline.calibrated_section import own_runs_text

    assert own_runs_text({"gns_dem_runs": 30, "gns_own_dem_runs": 30}) == ""
    assert own_runs_text({"gns_dem_runs": 60}) == ""
    assert own_runs_text({"gns_dem_runs": 60, "gns_own_dem_runs": 30}).startswith(" (30 of its own dataset")


def test_the_gns_routes_best_distinct_points_are_confirmed_by_the_dem():
    """The surrogate's favourite is a point the DEM scores badly: the DEM's confirmation, on packings
    of its own, chooses the point that made the data; near-duplicates and failed points are no
    candidates."""
    from calibration.confirmation import CONFIRM_SEED0, confirm, distinct_best

    model = Model()
    truth = [0.3, 0.8]
    column = replace(COLUMN, runout=model_runout(model, COLUMN, truth, SETTINGS, 11, RUNOUT, None))
    points = np.array([[0.9, 0.3], [0.9, 0.305], truth, [0.6, 0.6], [0.5, 0.5]])
    values = np.array([0.01, 0.011, 0.02, np.nan, 0.5])  # the GNS's objective: its best is wrong
    assert distinct_best(points, values, model, 3) == [0, 2, 4]  # the near-duplicate and the NaN left out
    assert distinct_best(points, values, model, 1) == [0]
    confirmation = confirm(model, column, points, values, SETTINGS, RUNOUT, None, n_candidates=2, n_packings=2)
    assert [c.seeds for c in confirmation.candidates] == [[CONFIRM_SEED0, CONFIRM_SEED0 + 1]] * 2
    assert confirmation.surrogate_values == [0.01, 0.02] and confirmation.dem_runs == 4
    scores = [c.mse for c in confirmation.candidates]
    # the truth on packings other than the data's: packing scatter only (here 0.0035, the wrong point 0.019)
    assert scores[1] < scores[0] / 2, scores
    assert confirmation.chosen == 1 and confirmation.theta == pytest.approx(truth)


def test_the_gns_slope_is_a_local_linear_fit_that_averages_over_roughness():
    """A curve linear in the unit box, plus a rough term like a rollout's: the kernel fit gives the
    slope back within the roughness's share; with no point near the centre it fits from those
    farther out; fewer points than the fit's unknowns is an error."""
    from calibration.confirmation import local_slope

    rng = np.random.default_rng(3)
    slope = np.array([[1.0, -0.5, 0.2], [2.0, 0.3, -1.0]])  # [K, p]
    points = rng.uniform(size=(60, 3))
    curves = (points - 0.5) @ slope.T + 0.01 * rng.standard_normal((60, 2))
    assert local_slope(points, curves, np.full(3, 0.5)) == pytest.approx(slope, abs=0.05)
    far = points[np.linalg.norm(points - 0.5, axis=1) > 0.45]  # none within 2 bandwidths of the centre
    assert len(far) >= 8
    assert local_slope(far, (far - 0.5) @ slope.T, np.full(3, 0.5)) == pytest.approx(slope, abs=1e-9)
    with pytest.raises(CalibrationError, match="needs 4 surrogate points"):
        local_slope(points[:3], curves[:3], np.full(3, 0.5))


def test_the_dem_corrects_the_gns_optimum_along_its_slopes_on_the_confirmation_packings():
    """A surrogate biased by +0.25 L* (a GNS off by about its test error) whose slopes are the
    DEM's: from its best point the refinement steps stay in the box and within the trust region,
    run on the confirmation packings, are counted, and the DEM's lowest of all is chosen."""
    from calibration.confirmation import CONFIRM_SEED0, TRUST_RADIUS, confirm, refine

    model = Model()
    column = replace(COLUMN, runout=model_runout(model, COLUMN, [0.3, 0.8], SETTINGS, 11, RUNOUT, None))
    grid = np.array([[m, e] for m in np.linspace(0.3, 0.9, 4) for e in np.linspace(0.3, 0.9, 3)])
    curves = np.array([model_runout(model, column, p, SETTINGS, 12, RUNOUT, None) for p in grid]) + 0.25
    confirmation = confirm(model, column, [[0.9, 0.9]], [0.01], SETTINGS, RUNOUT, None, 1, 2)
    refined = refine(model, column, confirmation, grid, curves, SETTINGS, RUNOUT, None, n_rounds=2)
    assert refined.candidates == confirmation.candidates and 1 <= len(refined.steps) <= 2
    assert refined.dem_runs == 2 * (1 + len(refined.steps)) and len(refined.predicted) == len(refined.steps)
    assert all(step.seeds == [CONFIRM_SEED0, CONFIRM_SEED0 + 1] for step in refined.steps)
    first = model.box.to_unit(list(refined.steps[0].parameters.values()))[0]
    assert np.all(np.abs(first - model.box.to_unit([0.9, 0.9])[0]) <= TRUST_RADIUS + 1e-9)
    scores = [c.mse for c in refined.checked]
    assert refined.chosen == int(np.argmin(scores))
    assert refined.theta == list(refined.checked[refined.chosen].parameters.values())
    # the linear model foresees a lower MSE than the point it steps from (it is a least-squares step)
    assert refined.predicted[0] < confirmation.candidates[0].mse
    assert refined.to_dict()["steps"][0]["seeds"] == [CONFIRM_SEED0, CONFIRM_SEED0 + 1]


def test_the_calibration_seed_moves_the_bayesian_optimisations_packing_and_design():
    """calibration.seed is the route's own randomness: another seed draws another initial design and
    runs every point on packing CALIBRATION_SEED + seed, as its values show."""
    from calibration.calibrated import CALIBRATION_SEED, bayesopt_model, runout_mse

    model = Model()
    histories = {seed: bayesopt_model(model, COLUMN, SETTINGS, RUNOUT, None, 2, 2, seed=seed) for seed in (0, 3)}
    assert histories[0].params[0] != histories[3].params[0]
    for seed, history in histories.items():
        for theta, value in zip(history.params, history.values):
            curve = model_runout(model, COLUMN, theta, SETTINGS, CALIBRATION_SEED + seed, RUNOUT, None)
            assert value == pytest.approx(runout_mse(curve, COLUMN.runout), rel=1e-12)


def test_the_report_names_the_routes_the_runoff_does_not_part_from_the_answer():
    """A route within 2 SE of the answer (paired, on the runoff's packings) is named with the span of
    the parameters; one outside it is not; without a tie, nothing is said."""
    from pipeline.calibrated_section import tie_lines

    def entry(route, mu, difference, se):
        versus = {"mse_difference": difference, "se": se}
        return {"route": route, "parameters": {"friction": mu}, "versus_answer": versus}

    result = {
        "answer": "BO",
        "answer_packings": 12,
        "runoff": [entry("BO", 0.3, 0.0, 0.0), entry("DoE", 0.5, 0.01, 0.02), entry("fit", 0.9, 0.08, 0.02)],
    }
    text = " ".join(tie_lines(result))
    assert "not told apart from 1 other route" in text and "DoE (+0.01 +- 0.02)" in text
    assert "friction 0.3-0.5" in text and "fit" not in text.replace("friction", "")
    result["runoff"] = result["runoff"][::2]
    assert tie_lines(result) == []
