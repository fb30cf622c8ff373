"""DoE: the factorial design, response-surface regression, ANOVA effect table, pure error, optimum;
the stage's jobs (pipeline/doe.py, pipeline/doe_section.py) on synthetic trajectories."""

import json

import numpy as np
import pytest
from statsmodels.stats.anova import anova_lm

from calibration.measured import load_column
from calibration.objective import objective
from doe.design import FACTORS, DesignError, Factor, design_cases, full_factorial
from doe.plots import plot_response_surfaces, plot_runout_comparison
from doe.regression import analyse, fit_surface, lack_of_fit, prediction_expression, pure_error

LEVELS = [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9]


def synthetic(design, coefficients, noise=0.0, seed=0):
    """Response b0 + b1 x1 + b2 x2 + b12 x1 x2 + b11 x1^2 + b22 x2^2 (coded factors) + N(0, noise)."""
    x1, x2 = design["x_friction"].to_numpy(), design["x_restitution"].to_numpy()
    b0, b1, b2, b12, b11, b22 = coefficients
    y = b0 + b1 * x1 + b2 * x2 + b12 * x1 * x2 + b11 * x1**2 + b22 * x2**2
    out = design.copy()
    out["mse"] = y + np.random.default_rng(seed).normal(0, noise, len(y))
    return out


def test_design_is_7x7_plus_replicated_centre():
    design = full_factorial()
    assert len(design) == 50 and design["run_id"].is_unique
    points = design[["friction", "restitution"]].drop_duplicates()
    assert len(points) == 49
    assert sorted(points["friction"].unique()) == LEVELS and sorted(points["restitution"].unique()) == LEVELS
    centre = design[(design.friction == 0.6) & (design.restitution == 0.6)]
    assert len(centre) == 2 and centre["seed"].nunique() == 2
    assert design.loc[design.replicate == 0, "seed"].nunique() == 1  # common packing seed over the factorial
    np.testing.assert_allclose(design["x_friction"], (design["friction"] - 0.6) / 0.3, atol=1e-12)
    np.testing.assert_allclose(sorted(design["x_restitution"].unique()), np.linspace(-1, 1, 7), atol=1e-12)
    with pytest.raises(DesignError, match="odd"):
        full_factorial(n_levels=6)
    with pytest.raises(DesignError, match="low"):
        Factor("friction", 0.9, 0.3)


def test_design_cases_take_the_measured_geometry():
    measured = load_column("data/measured/quartz_a6.csv")
    cases = design_cases(full_factorial(seed=5), measured, size_scale=4.0)
    assert len(cases) == 50
    case = cases["run_49"]
    assert (case.friction, case.restitution, case.seed, case.size_scale) == (0.6, 0.6, 6, 4.0)
    assert {c.aspect_ratio for c in cases.values()} == {6.0} and {c.L_i for c in cases.values()} == {0.02}
    assert cases["run_00"].friction == 0.3 and cases["run_00"].seed == 5


@pytest.mark.parametrize(
    "model, coefficients",
    [
        ("eq9", (0.713, -0.731, -0.04, -0.732, 0.0, 0.0)),  # the paper's eq. (9)
        ("quadratic", (1.2, -0.4, 0.3, 0.25, 0.6, 0.9)),
    ],
)
def test_regression_recovers_known_coefficients(model, coefficients):
    responses = synthetic(full_factorial(), coefficients, noise=0.02)
    fit = fit_surface(responses, model, FACTORS)
    estimate = fit.result.params.to_numpy()
    expected = coefficients[:4] if model == "eq9" else coefficients
    np.testing.assert_allclose(estimate, expected, atol=0.02)
    assert fit.r_squared > 0.99


def test_optimum_of_a_known_surface():
    # minimum at coded (0.3, -0.4): natural (0.69, 0.48), value 0.5
    design = full_factorial()
    x1, x2 = design["x_friction"] - 0.3, design["x_restitution"] + 0.4
    responses = design.assign(mse=0.5 + 0.8 * x1**2 + 0.6 * x2**2 + 0.3 * x1 * x2)
    best = fit_surface(responses, "quadratic", FACTORS).optimum()
    assert best["natural"]["friction"] == pytest.approx(0.69, abs=1e-4)
    assert best["natural"]["restitution"] == pytest.approx(0.48, abs=1e-4)
    assert best["predicted"] == pytest.approx(0.5, abs=1e-6)
    assert best["on_bound"] == []
    # the paper's bilinear eq. (9) falls fastest towards high friction and restitution: a corner
    corner = fit_surface(synthetic(design, (0.713, -0.731, -0.04, -0.732, 0, 0)), "eq9", FACTORS).optimum()
    assert corner["natural"] == pytest.approx({"friction": 0.9, "restitution": 0.9})
    assert corner["on_bound"] == ["friction", "restitution"] and corner["predicted"] < 0


def test_effect_table_matches_statsmodels_anova():
    responses = synthetic(full_factorial(), (0.7, -0.7, -0.04, -0.7, 0.2, 0.0), noise=0.4, seed=3)
    for model in ("eq9", "quadratic"):
        fit = fit_surface(responses, model, FACTORS)
        table = fit.effect_table().set_index("term")
        anova = anova_lm(fit.result, typ=3).drop(index=["Intercept", "Residual"])
        assert set(table.index) == set(anova.index)
        for term in anova.index:
            assert table.loc[term, "p_value"] == pytest.approx(anova.loc[term, "PR(>F)"], rel=1e-9)
            assert table.loc[term, "F"] == pytest.approx(anova.loc[term, "F"], rel=1e-9)
            # one-degree-of-freedom effect tests are the coefficient t-tests
            assert table.loc[term, "p_value"] == pytest.approx(fit.result.pvalues[term], rel=1e-6)
        np.testing.assert_allclose(table["logworth"], -np.log10(table["p_value"]))
        assert list(table["logworth"]) == sorted(table["logworth"], reverse=True)
    labels = list(fit_surface(responses, "eq9", FACTORS).effect_table()["source"])
    assert labels == ["friction(0.3,0.9)", "friction*restitution", "restitution(0.3,0.9)"]


def test_pure_error_and_lack_of_fit_from_the_replicated_centre():
    responses = synthetic(full_factorial(), (0.7, -0.7, 0.0, -0.7, 0.0, 0.0), noise=0.3, seed=1)
    centre = responses.loc[(responses.friction == 0.6) & (responses.restitution == 0.6), "mse"].to_numpy()
    pure = pure_error(responses, FACTORS)
    assert pure["df"] == 1 and pure["replicated"] == 1
    assert pure["sum_sq"] == pytest.approx((centre[0] - centre[1]) ** 2 / 2)
    fit = fit_surface(responses, "eq9", FACTORS)
    lof = lack_of_fit(fit, pure)
    assert lof["df"] == 50 - 4 - 1
    assert lof["sum_sq"] + pure["sum_sq"] == pytest.approx(fit.result.ssr)
    assert 0 <= lof["p_value"] <= 1


def test_analysis_summary_and_figures(tmp_path):
    responses = synthetic(full_factorial(), (1.0, -0.5, 0.1, -0.3, 0.4, 0.2), noise=0.05, seed=2)
    fits, summary = analyse(responses, FACTORS)
    json.dumps(summary)  # JSON-ready
    assert summary["n_runs"] == 50 and set(summary["models"]) == {"eq9", "quadratic"}
    assert summary["models"]["quadratic"]["r_squared"] > summary["models"]["eq9"]["r_squared"]
    best = responses.loc[responses.mse.idxmin()]
    assert summary["best_run"]["mse"] == pytest.approx(best.mse)
    assert prediction_expression(fits["eq9"]).startswith("mse = 1.")
    assert "((mu - 0.6)/0.3) * ((e - 0.6)/0.3)" in prediction_expression(fits["eq9"])
    plot_response_surfaces(fits, responses, tmp_path / "surface.png")
    measured = load_column("data/measured/quartz_a6.csv")
    t = np.linspace(0, 4, 41)
    plot_runout_comparison(measured, {"before": (t, 1.5 * t), "after": (t, 1.7 * t)}, tmp_path / "runout.png")
    assert (tmp_path / "surface.png").stat().st_size > 10_000 and (tmp_path / "runout.png").stat().st_size > 10_000


def test_case_rows_build_the_same_cases_in_the_dem_stage():
    from dem.grid import case_from_row
    from doe.study import case_rows

    measured = load_column("data/measured/quartz_a6.csv")
    design = full_factorial(n_levels=3)
    rows = case_rows(design, measured, "doe_quartz", size_scale=4.0, duration_over_tstar=4.0)
    cases = design_cases(design, measured, size_scale=4.0, duration_over_tstar=4.0)
    assert [r["case_id"] for r in rows] == list(cases)
    for row in rows:
        assert case_from_row(row) == cases[row["case_id"]]  # CollapseCase equality ignores the name


def test_study_on_synthetic_trajectories(tmp_path):
    """Responses, analysis and report section from trajectories whose runout is known exactly:
    L*(t; mu, e) = g(mu, e) L*_measured(t), so the MSE is (g - 1)^2 mean(L*_measured^2)."""
    from test_objective import front_trajectory

    from dem.atomic import write_json
    from dem.runout import RunoutError, RunoutMethod
    from dem.trajectory import write_trajectory
    from doe.study import collect_responses, read_responses, run_analysis, write_responses
    from pipeline.doe_section import report_section

    connected = RunoutMethod("connected_front")  # front_trajectory builds a connected-deposit front

    measured = load_column("data/measured/quartz_a6.csv")
    t_frames = np.arange(0, 4.01, 0.25)
    base = np.interp(t_frames, measured.t_over_tstar, measured.runout, left=0.0, right=measured.runout[-1])

    def gain(mu, e):
        return 1 + 0.8 * (0.6 - mu) + 0.3 * (e - 0.5)

    def write_run(path, mu, e):
        traj = front_trajectory(measured.L_i * (1 + gain(mu, e) * base))
        traj.attrs.update(friction=mu, restitution=e, wall_time_s=1.5)
        write_trajectory(path, traj)
        return path

    design = full_factorial(n_levels=3)
    paths = {r.run_id: write_run(tmp_path / f"{r.run_id}.h5", r.friction, r.restitution) for r in design.itertuples()}
    responses = collect_responses(design, paths, measured, connected)
    g = gain(responses.friction, responses.restitution)
    np.testing.assert_allclose(responses["mse"], (g - 1) ** 2 * np.mean(measured.runout**2), rtol=1e-4, atol=1e-8)
    np.testing.assert_allclose(responses["L_star_t3.5"], 6.0 * g, rtol=1e-4)

    fits, summary = run_analysis(responses, FACTORS, ["eq9", "quadratic"])
    folder = tmp_path / "doe"
    write_json(folder / "analysis.json", summary)
    write_responses(folder / "responses.csv", responses)
    # the responses state their runout method; read back by it, refused by another
    assert set(responses["runout_method"]) == {json.dumps(connected.to_config(), sort_keys=True)}
    assert read_responses(folder / "responses.csv", connected)["mse"].tolist() == pytest.approx(
        responses["mse"].tolist()
    )
    with pytest.raises(RunoutError, match="DoE responses .*responses.csv.*scored with runout"):
        read_responses(folder / "responses.csv", RunoutMethod("connected_front_reached"))
    plot_response_surfaces(fits, responses, folder / "response_surface.png")
    # the MSE is exactly quadratic in (mu, e) here: the quadratic surface fits it and finds g = 1
    assert summary["models"]["quadratic"]["r_squared"] == pytest.approx(1.0, abs=1e-6)
    best = summary["models"]["quadratic"]["optimum"]
    assert gain(best["natural"]["friction"], best["natural"]["restitution"]) == pytest.approx(1.0, abs=1e-3)
    validation = {
        "quartz": {
            "quadratic": write_run(tmp_path / "val.h5", best["natural"]["friction"], best["natural"]["restitution"])
        }
    }
    section_path = tmp_path / "report" / "doe.md"
    text = report_section(
        ["quartz"],
        [measured.source],
        [folder / "analysis.json"],
        [paths["run_4"]],
        validation,
        [folder / "runout.png"],
        {"quartz": []},
        section_path,
        runout=connected,
    )
    assert "| friction(0.3,0.9) |" in text and "**MSE = 0.000**" in text
    assert "](../doe/response_surface.png)" in text and (folder / "runout.png").stat().st_size > 10_000


def test_stage_jobs_on_synthetic_trajectories(tmp_path):
    """pipeline.doe's entry functions, one per Snakemake job, on the files the rules name: design
    table, responses + analysis (runout recorded) + surface, a real DEM validation run at the
    optimum with the configured engine, section from the files alone (pipeline.doe_section)."""
    from test_objective import front_trajectory

    import pipeline.doe
    import pipeline.doe_section
    from dem.runout import RunoutMethod
    from dem.trajectory import read_trajectory, write_trajectory
    from doe.design import read_design

    connected = RunoutMethod("connected_front")
    measured_path = "data/measured/quartz_a6.csv"
    measured = load_column(measured_path)
    doe = {"levels": 3, "models": ["eq9", "quadratic"], "size_scale": 4.0, "duration_over_tstar": 4.0}
    t_frames = np.arange(0, 4.01, 0.25)
    base = np.interp(t_frames, measured.t_over_tstar, measured.runout, left=0.0, right=measured.runout[-1])

    def run(mu, e):
        traj = front_trajectory(measured.L_i * (1 + (1 + 0.8 * (0.6 - mu) + 0.3 * (e - 0.5)) * base))
        traj.attrs.update(friction=mu, restitution=e, wall_time_s=1.5)
        return traj

    folder = tmp_path / "results/doe/quartz"
    table = pipeline.doe.design(measured_path, doe, folder / "design.csv")
    assert read_design(folder / "design.csv")["run_id"].tolist() == table["run_id"].tolist()
    runs = tmp_path / "results/dem/doe_quartz/trajectories"
    for r in table.itertuples():
        write_trajectory(runs / f"{r.run_id}.h5", run(r.friction, r.restitution))
    summary = pipeline.doe.analyse(
        folder / "design.csv",
        measured_path,
        sorted(runs.glob("*.h5")),
        doe,
        connected.to_config(),
        folder / "responses.csv",
        folder / "analysis.json",
        folder / "response_surface.png",
    )
    written = json.loads((folder / "analysis.json").read_text())
    assert written["runout"] == connected.to_config() == summary["runout"]
    assert written["n_runs"] == len(table) and (folder / "response_surface.png").stat().st_size > 10_000

    # a real (coarse: size_scale 8, ~230 grains) DEM run at the quadratic model's optimum
    fields = {"size_scale": 8.0, "duration_over_tstar": 4.0, "seed": 0}
    mse = pipeline.doe.validate(
        folder / "analysis.json",
        measured_path,
        "quadratic",
        fields,
        {"engine": "builtin"},
        connected.to_config(),
        folder / "validation/quadratic.h5",
    )
    validation = read_trajectory(folder / "validation/quadratic.h5")
    optimum = written["models"]["quadratic"]["optimum"]["natural"]
    assert validation.attrs["engine"] == "builtin" and validation.attrs["size_scale"] == 8.0
    assert (validation.attrs["friction"], validation.attrs["restitution"]) == pytest.approx(
        (optimum["friction"], optimum["restitution"])
    )
    assert mse == pytest.approx(objective(validation, measured, connected), rel=1e-12) and mse > 0

    section = tmp_path / "results/report/doe.md"
    text = pipeline.doe_section.write_section(
        ["quartz"],
        [measured_path],
        [folder / "analysis.json"],
        [runs / "run_4.h5"],
        [folder / "validation/quadratic.h5"],
        [folder / "runout.png"],
        {"quartz": []},
        section,
        runout=connected.to_config(),
    )
    assert section.read_text() == text and f"**MSE = {mse:.3f}**" in text  # the validation run's score
    assert "](../doe/quartz/response_surface.png)" in text and (folder / "runout.png").stat().st_size > 10_000
