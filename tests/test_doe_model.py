"""DoE of the calibrated model: the face-centred central composite design and the 3-level full
factorial around it, the k-factor response surfaces (known coefficients, optimum inside and on a
bound, ANOVA and lack of fit), the k-factor figure, both designs from one campaign on a known
response, and the route on real DEM runs of a tiny column (77 grains) with one failing run."""

import json

import numpy as np
import pytest

from calibration.calibrated import CALIBRATION_SEED, model_record
from calibration.mechanisms import get_mechanisms
from calibration.model import Model
from calibration.objective import runout_mse
from dem.integrate import SimulationError
from doe.design import (
    FACTORS,
    DesignError,
    Factor,
    centre_run_id,
    face_centred_ccd,
    full_factorial,
    three_level_factorial,
)
from doe.model_study import CCD, FULL_FACTORIAL
from doe.plots import plot_surface_pairs
from doe.regression import (
    RegressionError,
    analyse,
    fit_surface,
    formula,
    lack_of_fit,
    prediction_expression,
    pure_error,
)
from tests.test_calibrated import COLUMN, RUNOUT, SETTINGS  # the tiny measured column of the calibrated stage

THREE = (Factor("friction", 0.3, 0.9), Factor("restitution", 0.3, 0.9), Factor("bond_number", 0.0, 60.0))
X = [f"x_{f.name}" for f in THREE]


def quadratic_bowl(design, centre, curvature, floor=0.5):
    """Response floor + (x - centre)^T curvature (x - centre) on the coded factors: its minimum over
    all x is `floor` at coded `centre`."""
    offset = design[X].to_numpy() - np.asarray(centre)
    return design.assign(mse=floor + np.einsum("ni,ij,nj->n", offset, np.asarray(curvature), offset))


def test_face_centred_ccd_has_corners_faces_and_replicated_centre():
    design = face_centred_ccd(THREE, centre_replicates=3, seed=7)
    assert len(design) == 2**3 + 2 * 3 + 1 + 3 and design["run_id"].tolist()[:2] == ["run_00", "run_01"]
    coded = design[X].to_numpy()
    assert set(np.unique(coded)) == {-1.0, 0.0, 1.0}
    nonzero = (coded != 0).sum(axis=1)
    assert (nonzero == 3).sum() == 8 and (nonzero == 1).sum() == 6 and (nonzero == 0).sum() == 4
    assert len({tuple(row) for row in coded[nonzero > 0]}) == 14  # every corner and face centre once
    for f in THREE:  # alpha = 1: every run within the bounds, coded as full_factorial codes
        assert design[f.name].between(f.low, f.high).all()
        np.testing.assert_allclose(design[f"x_{f.name}"], f.code(design[f.name]), atol=1e-12)
    centre = design[nonzero == 0]
    assert centre["replicate"].tolist() == [0, 1, 2, 3] and centre["seed"].tolist() == [7, 8, 9, 10]
    assert set(design.loc[design.replicate == 0, "seed"]) == {7}  # common packing over the design
    assert centre_run_id(design) == "run_14"
    assert list(design.columns) == ["run_id", *[f.name for f in THREE], *X, "seed", "replicate"]
    # k = 2: the 3 x 3 full factorial, in another order
    square, factorial = face_centred_ccd(FACTORS, 1), full_factorial(FACTORS, 3, 1)
    assert list(square.columns) == list(factorial.columns)
    key = ["friction", "restitution", "seed", "replicate"]
    assert sorted(map(tuple, square[key].to_numpy())) == sorted(map(tuple, factorial[key].to_numpy()))
    with pytest.raises(DesignError, match="at least 2"):
        face_centred_ccd(THREE[:1])
    with pytest.raises(DesignError, match="must differ"):
        face_centred_ccd([THREE[0], THREE[0]])
    with pytest.raises(DesignError, match="centre_replicates"):
        face_centred_ccd(THREE, centre_replicates=-1)


def test_the_three_level_factorial_is_the_ccd_and_the_grid_points_it_lacks():
    design = three_level_factorial(THREE, centre_replicates=3, seed=7)
    assert len(design) == 27 + 3 and design["run_id"].is_unique
    ccd = face_centred_ccd(THREE, centre_replicates=3, seed=7)
    # the CCD's rows first, exactly (same run ids, values, packing seeds): its runs are shared
    assert design[design.ccd].drop(columns="ccd").reset_index(drop=True).equals(ccd)
    assert design["ccd"].tolist() == [True] * 18 + [False] * 12
    coded = design[X].to_numpy()
    assert len({tuple(row) for row in coded}) == 27  # every grid point, the centre repeated
    rest = design[~design.ccd]
    assert ((rest[X] == 0).sum(axis=1) == 1).all()  # k = 3: the 12 edge midpoints
    assert set(rest["seed"]) == {7} and set(rest["replicate"]) == {0}  # on the CCD's common packing
    assert design["run_id"].tolist()[18] == "run_18"
    for f in THREE:
        np.testing.assert_allclose(design[f"x_{f.name}"], f.code(design[f.name]), atol=1e-12)
    square = three_level_factorial(FACTORS, 1)  # k = 2: the CCD already is the 3 x 3 grid
    assert square.ccd.all() and len(square) == 10


def test_quadratic_fit_recovers_a_known_three_factor_surface_and_its_optimum():
    design = face_centred_ccd(THREE, centre_replicates=2)
    curvature = np.array([[0.8, 0.15, 0.1], [0.15, 0.6, -0.1], [0.1, -0.1, 0.5]])
    centre = np.array([0.3, -0.4, 0.5])
    fit = fit_surface(quadratic_bowl(design, centre, curvature), "quadratic", THREE)
    assert len(fit.result.params) == 10 and len(fit_surface(design.assign(mse=1.0), "eq9", THREE).result.params) == 7
    params = fit.result.params
    expected = {"Intercept": 0.5 + centre @ curvature @ centre}
    for i, x in enumerate(X):
        expected[x] = -2 * (curvature @ centre)[i]
        expected[f"I({x} ** 2)"] = curvature[i, i]
        for j in range(i + 1, 3):
            expected[f"{x}:{X[j]}"] = 2 * curvature[i, j]
    assert set(params.index) == set(expected)
    for term, value in expected.items():
        assert params[term] == pytest.approx(value, abs=1e-10), term
    best = fit.optimum()
    assert [best["coded"][f.name] for f in THREE] == pytest.approx(centre, abs=1e-5)
    assert best["natural"]["bond_number"] == pytest.approx(45.0, abs=1e-3)
    assert best["predicted"] == pytest.approx(0.5, abs=1e-9) and best["on_bound"] == []
    # the bowl's centre beyond the bond-number bound: the optimum sits on it, the rest at their best
    uncoupled = np.array([[0.8, 0.15, 0.0], [0.15, 0.6, 0.0], [0.0, 0.0, 0.5]])
    edge = fit_surface(quadratic_bowl(design, [0.3, -0.4, 1.5], uncoupled), "quadratic", THREE).optimum()
    assert edge["natural"] == pytest.approx({"friction": 0.69, "restitution": 0.48, "bond_number": 60.0}, abs=1e-4)
    assert edge["on_bound"] == ["bond_number"] and edge["predicted"] == pytest.approx(0.5 + 0.5 * 0.5**2)
    expression = prediction_expression(fit)
    assert "((Bo - 30)/30)^2" in expression and "((mu - 0.6)/0.3) * ((Bo - 30)/30)" in expression


def test_anova_and_lack_of_fit_on_noisy_three_factor_runs():
    design = face_centred_ccd(THREE, centre_replicates=5)
    x_f, x_r, x_b = (design[x].to_numpy() for x in X)
    noise = np.random.default_rng(4).normal(0, 0.02, len(design))
    truth = 1.0 + 0.8 * x_f - 0.5 * x_b + 0.6 * x_f * x_b + 0.4 * x_r**2
    responses = design.assign(mse=truth + noise)
    fits, summary = analyse(responses, THREE, models=("quadratic",))
    json.dumps(summary)  # JSON-ready
    effects = summary["models"]["quadratic"]["effects"]
    assert len(effects) == 9 and summary["n_runs"] == 20
    active = {"friction(0.3,0.9)", "bond_number(0,60)", "friction*bond_number", "restitution*restitution"}
    assert {e["source"] for e in effects[:4]} == active  # sorted by LogWorth: the real effects first
    assert all(e["p_value"] < 1e-6 for e in effects[:4]) and all(e["p_value"] > 1e-3 for e in effects[4:])
    pure = summary["pure_error"]
    centre = responses.loc[(design[X] == 0).all(axis=1), "mse"].to_numpy()
    assert pure["df"] == 5 and pure["replicated"] == 1  # six centre runs
    assert pure["sum_sq"] == pytest.approx(np.sum((centre - centre.mean()) ** 2))
    lof = summary["models"]["quadratic"]["lack_of_fit"]
    assert lof["df"] == 20 - 10 - 5 and lof["sum_sq"] + pure["sum_sq"] == pytest.approx(fits["quadratic"].result.ssr)
    assert lof["p_value"] > 0.05  # the surface is quadratic: no lack of fit
    # a three-factor interaction is outside the quadratic model and orthogonal to it on this design:
    # it all goes to the residual, and the replicated centre shows it is not packing noise
    cubic = fit_surface(responses.assign(mse=responses.mse + 0.3 * x_f * x_r * x_b), "quadratic", THREE)
    assert lack_of_fit(cubic, pure_error(responses, THREE))["p_value"] < 1e-3


def test_a_design_that_cannot_separate_the_terms_is_refused():
    design = face_centred_ccd(THREE, centre_replicates=3)
    corners_and_centre = design[(design[X] != 0).sum(axis=1) != 1]  # no face centres
    with pytest.raises(RegressionError, match="cannot separate the 10 coefficients"):
        fit_surface(corners_and_centre.assign(mse=1.0), "quadratic", THREE)  # squares: all alike
    with pytest.raises(RegressionError, match="cannot fit the quadratic model \\(10 coefficients\\)"):
        fit_surface(corners_and_centre.head(9).assign(mse=1.0), "quadratic", THREE)
    assert formula("eq9", THREE).count(":") == 3


def test_model_doe_on_dem_runs_records_a_failed_run_and_fits_without_it(monkeypatch, tmp_path):
    """Cohesion model (mu, e, Bond number): 8 corners + 6 faces + centre + 1 replicate = 16 real DEM
    runs; the run at the high-Bond-number face centre is made to blow up."""
    import doe.model_study
    from doe.model_study import fitted_runs, model_doe, model_factors

    real = doe.model_study.model_runout
    seeds = []

    def sometimes_blows_up(model, column, theta, settings, seed, runout, dem_config):
        seeds.append(seed)
        if list(theta) == [0.6, 0.6, 60.0]:
            raise SimulationError("grains left the domain at step 123")
        return real(model, column, theta, settings, seed, runout, dem_config)

    monkeypatch.setattr(doe.model_study, "model_runout", sometimes_blows_up)
    model = Model(get_mechanisms(["cohesion"])[0])
    done = []
    responses, studies = model_doe(model, COLUMN, SETTINGS, RUNOUT, None, centre_replicates=1, progress=done.append)
    assert list(studies) == [CCD]
    summary, fit = studies[CCD]
    assert fit.optimum() == summary["models"]["quadratic"]["optimum"]  # the surface the summary reports
    assert len(responses) == 16 and done[-1] == 1.0 and len(done) == 16
    assert seeds == [CALIBRATION_SEED] * 15 + [CALIBRATION_SEED + 1]  # common packing, the replicate another
    failed = responses[responses.failure != ""]
    assert failed["run_id"].tolist() == ["run_13"] and np.isnan(failed["mse"]).all()
    assert summary["failed"] == {"run_13": "SimulationError: grains left the domain at step 123"}
    assert "1 of 16 DEM runs failed and are left out of the fit: run_13" in summary["failures"]
    assert summary["n_runs"] == 16 and summary["n_fitted"] == 15 and summary["design"] == "face-centred CCD"
    ran = fitted_runs(responses)
    row = ran.iloc[0]
    curve = row[[f"L_star_t{t:g}" for t in COLUMN.t_over_tstar]].to_numpy(float)
    assert row["mse"] == pytest.approx(runout_mse(curve, COLUMN.runout)) and (ran.dem_wall_time_s > 0).all()
    quadratic = summary["models"]["quadratic"]
    assert len(quadratic["coefficients"]) == 10 and len(quadratic["effects"]) == 9
    assert quadratic["lack_of_fit"]["df"] == 15 - 10 - 1 and summary["pure_error"]["df"] == 1
    for name, (low, high) in zip(model.parameter_names, model.bounds):  # decoded: to rounding
        assert low - 1e-12 <= quadratic["optimum"]["natural"][name] <= high + 1e-12
    assert summary["models"]["quadratic"]["effects"][0]["source"] == "bond_number(0,60)"  # cohesion dominates
    json.dumps(summary)
    fit = fit_surface(ran, "quadratic", model_factors(model))
    plot_surface_pairs(fit, responses, tmp_path / "surface.png", title="tiny")
    assert (tmp_path / "surface.png").stat().st_size > 10_000


def test_both_designs_come_from_one_campaign_and_fit_their_own_runs(monkeypatch):
    """A known quadratic response in place of the DEM: the full factorial runs 27 + 2 points, the
    CCD's 15 + 2 among them, each design's surface is fitted to its own runs only."""
    import doe.model_study
    from doe.model_study import model_doe

    factors = THREE
    centre = np.array([0.3, -0.4, 0.5])  # coded optimum of the response
    calls = []

    def quadratic_runout(model, column, theta, settings, seed, runout, dem_config):
        calls.append((tuple(theta), seed))
        x = np.array([f.code(v) for f, v in zip(factors, theta)])
        # an MSE of (x - centre)^2 on a curve: the measured curve shifted by that much at every time
        return np.asarray(COLUMN.runout) + np.sqrt(np.sum((x - centre) ** 2))

    monkeypatch.setattr(doe.model_study, "model_runout", quadratic_runout)
    monkeypatch.setattr(doe.model_study, "model_factors", lambda model: factors)
    model = Model(get_mechanisms(["cohesion"])[0])
    responses, studies = model_doe(model, COLUMN, SETTINGS, RUNOUT, None, centre_replicates=2, full_factorial=True)
    assert list(studies) == [CCD, FULL_FACTORIAL] and len(calls) == len(responses) == 29
    assert len(set(calls)) == 29  # one campaign: no point run twice on one packing
    ccd, full = studies[CCD][0], studies[FULL_FACTORIAL][0]
    assert (ccd["n_runs"], full["n_runs"]) == (17, 29) and responses["ccd"].sum() == 17
    assert ccd["dem_seconds"] < full["dem_seconds"]
    assert ccd["design"] == CCD and full["design"] == FULL_FACTORIAL
    for summary in (ccd, full):  # an exact quadratic: both surfaces find its optimum
        optimum = summary["models"]["quadratic"]["optimum"]
        assert [optimum["coded"][f.name] for f in factors] == pytest.approx(centre, abs=1e-6)
    # the CCD-only campaign: the same CCD runs and surface
    calls.clear()
    alone, alone_studies = model_doe(model, COLUMN, SETTINGS, RUNOUT, None, centre_replicates=2)
    assert len(calls) == 17 and list(alone_studies) == [CCD]
    assert alone_studies[CCD][0]["models"] == ccd["models"]


def test_the_stage_writes_the_doe_result_responses_and_figure(tmp_path):
    """Base model (mu, e): the 3 x 3 design + 1 centre replicate = 10 real DEM runs."""
    from doe.study import read_responses
    from pipeline.calibrated_column import CalibratedColumn
    from pipeline.calibrated_doe import run_model_doe

    csv = tmp_path / "tiny.csv"
    csv.write_text(
        "column,material,aspect_ratio,L_i,kind,x,value,std\n"
        + "".join(f"tiny,quartz,2,0.01,runout,{t},{v},\n" for t, v in zip(COLUMN.t_over_tstar, COLUMN.runout))
    )
    model_json = tmp_path / "model.json"
    model_json.write_text(json.dumps(model_record(Model(), "the config asks for the base model (mu, e)", "tiny")))
    out = tmp_path / "calibrated" / "tiny"
    job = CalibratedColumn.read(
        csv, model_json, {"size_scale": 4.0, "channel_width": 0.01}, runout=RUNOUT.to_config(), dem=None, name="tiny"
    )
    result = run_model_doe(
        job, out / "doe.json", out / "doe_responses.csv", out / "doe_surface.png", {"doe_centre_replicates": 1},
        out_full_factorial=(out / "doe_full_factorial.json", out / "doe_full_factorial_surface.png"),
    )  # fmt: skip
    written = json.loads((out / "doe.json").read_text())
    assert written["route"] == "base, DoE (face-centred CCD, quadratic)"
    assert written["parameters"] == ["friction", "restitution"] and written["why"].startswith("the config asks")
    assert written["dem_runs"] == 10 and written["n_fitted"] == 10 and written["failed"] == {}
    assert written["optimum"] == result["optimum"] == written["models"]["quadratic"]["optimum"]["natural"]
    assert written["seconds"] > 0 and written["runout"] == RUNOUT.to_config()
    responses = read_responses(out / "doe_responses.csv", RUNOUT)
    assert len(responses) == 10 and responses["mse"].notna().all()
    assert (out / "doe_surface.png").stat().st_size > 10_000
    # two parameters: the CCD already is the 3 x 3 grid, so the full factorial is the same runs and fit
    full = json.loads((out / "doe_full_factorial.json").read_text())
    assert full["route"] == "base, DoE (3-level full factorial, quadratic)" and full["dem_runs"] == 10
    assert full["optimum"] == written["optimum"] and full["models"] == written["models"]
    assert (out / "doe_full_factorial_surface.png").stat().st_size > 10_000
