"""A lab campaign: several columns of one material, calibrated as one parameter set by each route,
each column predicted from the others (calibration/campaign.py, doe/campaign_study.py,
pipeline/campaign.py, workflow/rules/campaign.smk).

The DAG test calibrates data/test/tiny_campaign.csv: quartz columns of a = 1, 2 and 4 made by the
builtin DEM with a hidden mechanism (rolling resistance, rolling friction 0.15; mu 0.45, e 0.5; its
own packing; noise std 0.05 in L*), given on the command line as a user would, through
config/tiny_all.yaml's diagnosis (which must find the model) and both routes.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from calibration.calibrated import Validation
from calibration.campaign import SCATTER_LEVEL, Campaign, CampaignError, CampaignRunner, scatter_bound
from calibration.design_runs import SimulationSettings
from calibration.measured import MeasuredDataError, read_measured
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import get_mechanisms
from calibration.model import Model
from calibration.synthetic import LAB_RUNOUT, HiddenTruth, liggghts_measurement, synthetic_columns
from dem import grid
from dem.runout import RunoutMethod
from dem.trajectory import read_attrs
from pipeline.campaign import CampaignResult, SurrogateCost, run_campaign_route
from pipeline.cases import case_table
from pipeline.config import ConfigError, check_cross_keys
from tests.conftest import TINY_ALL
from tests.test_bad_input import as_run_sh_main
from tests.test_workflow import copy_workflow, job_stats, snakemake

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN_CSV = ROOT / "data/test/tiny_campaign.csv"


def column(name: str, a: float, std: float | None = None, material: str = "quartz") -> MeasuredColumn:
    t = np.array([0.5, 1.0, 1.5, 2.0])
    return MeasuredColumn(
        name=name,
        material=material,
        aspect_ratio=a,
        L_i=0.02,
        t_over_tstar=t,
        runout=a * t / 2,
        runout_std=None if std is None else np.full(4, std),
        source="test.csv",
    )


def test_the_campaign_objective_weighs_each_column_by_its_stated_noise():
    noisy = Campaign("lab", (column("a1", 1, std=0.1), column("a2", 2, std=0.2)))
    assert noisy.weights == pytest.approx([1.6, 0.4])  # 1/0.01 : 1/0.04, mean 1
    assert noisy.objective([0.01, 0.04]) == pytest.approx((1.6 * 0.01 + 0.4 * 0.04) / 2)
    assert noisy.objective([0.01, 0.04], ["a2"]) == pytest.approx(0.04)
    assert noisy.others("a1") == ["a2"]
    assert math.isnan(noisy.objective([0.01, math.nan]))  # a failed run is not averaged away
    unstated = Campaign("lab", (column("a1", 1, std=0.1), column("a2", 2)))
    assert list(unstated.weights) == [1.0, 1.0]
    assert "equal weights" in unstated.weighting and "1 / the stated variance" in noisy.weighting


def test_a_campaign_is_of_one_material_and_of_columns_of_their_own_names():
    with pytest.raises(CampaignError, match="test.csv: column 'b' is of material 'copper'.*one material"):
        Campaign("lab", (column("a", 1), column("b", 2, material="copper")))
    with pytest.raises(CampaignError, match="two columns of the same name"):
        Campaign("lab", (column("a", 1), column("a", 2)))
    with pytest.raises(CampaignError, match="a campaign holds 2 or more"):
        Campaign("lab", (column("a", 1),))


def test_the_scatter_bound_is_the_miss_the_true_parameters_would_show():
    curves = [[0.0, 1.0], [0.2, 1.4], [0.4, 1.8], [0.2, 1.4]]
    run = Validation(
        "r", {}, [1, 2, 3, 4], [1.0, 2.0], curves, {}, [0.2, 1.4], list(np.std(curves, 0, ddof=1)), 0, [], 0
    )
    packing = np.mean(np.var(curves, 0, ddof=1))
    assert scatter_bound(run, column("a", 1, std=0.1)) == pytest.approx(SCATTER_LEVEL * (packing * 1.25 + 0.01))
    assert scatter_bound(run, column("a", 1)) == pytest.approx(SCATTER_LEVEL * packing * 1.25)


def campaign_csv(path: Path, rows: list[str]) -> Path:
    path.write_text("column,material,aspect_ratio,L_i,kind,x,value,std\n" + "\n".join(rows) + "\n")
    return path


def curve_rows(name: str, material: str, a: float, L_i: float = 0.02) -> list[str]:
    return [f"{name},{material},{a},{L_i},runout,{t},{a * t / 2:.3f}," for t in (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5)]


def test_bad_campaigns_are_refused_before_any_job_naming_file_line_and_column(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    mixed = campaign_csv(tmp_path / "mixed.csv", curve_rows("q1", "quartz", 1) + curve_rows("c2", "copper", 2))
    with pytest.raises(ConfigError, match=rf"measured.mine: {mixed}, line 9, column 'material': column 'c2' is of"):
        as_run_sh_main(mixed)
    twice = campaign_csv(tmp_path / "twice.csv", curve_rows("q", "quartz", 1) + curve_rows("q", "quartz", 2))
    with pytest.raises(MeasuredDataError, match=rf"{twice}, line 9, column 'aspect_ratio'.*two columns of one name"):
        read_measured(twice)
    # 2 mm long: 4.7 grains across at the diagnosis' size_scale 1 (dem.min_grains_across 8)
    small = campaign_csv(tmp_path / "small.csv", curve_rows("q1", "quartz", 1) + curve_rows("q2", "quartz", 2, 0.002))
    with pytest.raises(
        ConfigError,
        match=rf"diagnosis.size_scale \(measured 'mine': {small}, line 9, column 'L_i' of measured column 'q2'\)",
    ):
        as_run_sh_main(small, "diagnosis={size_scale: 1}")
    good = campaign_csv(tmp_path / "good.csv", curve_rows("q1", "quartz", 1) + curve_rows("q2", "quartz", 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        config = as_run_sh_main(good)  # a campaign on the command line is calibrated as a campaign
        assert "mine" not in config["inverse"]["measured"]
        for key, settings in (
            ("doe.measured", ["doe={measured: [mine]}"]),
            ("inverse.measured", ["inverse={measured: [mine]}"]),
        ):
            with pytest.raises(ConfigError, match=rf"config key {re.escape(key)}: 'mine' .* is a campaign of columns"):
                as_run_sh_main(good, *settings)


def campaign_dataset_rows(csv: Path, *settings: str) -> list[dict]:
    """The case-table rows of the GNS dataset of campaign `mine` (csv) under config/config.yaml."""
    config = as_run_sh_main(csv, *settings)
    table = case_table(config, check_cross_keys(config, grid.case_table(config)))
    return [row for row in table.values() if row["dataset"] == "campaign_mine"]


def test_a_campaign_dataset_given_by_hand_adds_no_case_for_a_column_on_its_geometries(tmp_path, monkeypatch):
    """Given by hand (calibration.campaign_geometry), a campaign's GNS dataset is the same with a
    third column on its geometries as without it: the column costs it no DEM run. Derived from the
    columns, the dataset moves cases to the new column, as many as the GNS route reports."""
    monkeypatch.chdir(ROOT)
    two = campaign_csv(tmp_path / "two.csv", curve_rows("q1", "quartz", 1) + curve_rows("q2", "quartz", 2))
    three = campaign_csv(
        tmp_path / "three.csv",
        curve_rows("q1", "quartz", 1) + curve_rows("q2", "quartz", 2) + curve_rows("q4", "quartz", 4),
    )
    given = "calibration={campaign_geometry: {mine: {aspect_ratio: [1, 2, 4, 6], L_i: [0.02]}}}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        before, after = campaign_dataset_rows(two, given), campaign_dataset_rows(three, given)
        assert len(before) == 30 and before == after
        assert [row["template"]["aspect_ratio"] for row in before[:5]] == [1, 2, 4, 6, 1]
        derived = [campaign_dataset_rows(csv) for csv in (two, three)]
    moved = [a["case_id"] for a, b in zip(*derived, strict=True) if a["template"] != b["template"]]
    cost = SurrogateCost(dataset_runs=30, dataset_seconds=60.0, training_seconds=100.0)
    (runs, seconds), why = cost.added_column(2, 10.0, geometry_given=False)
    assert runs == len(moved) == 20 and seconds == pytest.approx(20 / 30 * 60 + 100 + 10 / 2)
    assert "moves 20 of its 30 cases" in why and "trained again" in why
    assert cost.added_column(2, 10.0, geometry_given=True)[0] == (0.0, 5.0)


@pytest.mark.parametrize(
    "geometry, message",
    [
        (
            "{mine: {aspect_ratio: [2, 4], L_i: [0.02]}}",
            r"line 2, column 'aspect_ratio': column 'q1' \(aspect_ratio = 1\) lies outside the range of its "
            r"campaign's GNS dataset, aspect_ratio in \[2, 4\]: the GNS would extrapolate; add 1 to "
            r"calibration.campaign_geometry.mine.aspect_ratio",
        ),
        (
            "{mine: {aspect_ratio: [1, 4], L_i: [0.02]}}",
            r"line 9, column 'aspect_ratio': column 'q2' \(aspect_ratio = 2\) lies between the geometries of its "
            r"campaign's GNS dataset \(aspect_ratio \[1, 4\]\): no run of the dataset starts its rollouts",
        ),
        (
            "{mine: {aspect_ratio: [1, 2], L_i: [0.03]}}",
            r"line 2, column 'L_i': column 'q1' \(L_i = 0.02\) lies outside",
        ),
        (
            "{mine: {aspect_ratio: [1, 2], L_i: [0.02], duration_over_tstar: 3}}",
            r"line 2, column 'x': column 'q1' is measured to t/t\* = 3.5, past the 3 t\* its campaign's GNS "
            r"dataset simulates",
        ),
    ],
    ids=["outside", "between", "L_i", "duration"],
)
def test_a_column_off_its_campaigns_given_geometry_is_refused_before_any_job(tmp_path, monkeypatch, geometry, message):
    monkeypatch.chdir(ROOT)
    good = campaign_csv(tmp_path / "good.csv", curve_rows("q1", "quartz", 1) + curve_rows("q2", "quartz", 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ConfigError, match=rf"config key calibration.campaign_geometry.mine: {good}, {message}"):
            as_run_sh_main(good, f"calibration={{campaign_geometry: {geometry}}}")
        with pytest.raises(ConfigError, match=r"campaign_geometry.other: 'other' is not a campaign .*\['mine'\]"):
            as_run_sh_main(good, "calibration={campaign_geometry: {other: {aspect_ratio: [1], L_i: [0.02]}}}")
        four = campaign_csv(tmp_path / "four.csv", sum((curve_rows(f"q{a}", "quartz", a) for a in (1, 2, 4, 6)), []))
        with pytest.raises(ConfigError, match=r"calibration.gns_cases: 3 cases cannot cover the 4 columns of campaign"):
            as_run_sh_main(four, "calibration={gns_cases: 3}")
        with pytest.raises(ConfigError, match=r"calibration.gns_cases: 3 cases cannot cover the 4 geometries"):
            as_run_sh_main(
                good, "calibration={gns_cases: 3, campaign_geometry: {mine: {aspect_ratio: [1, 2], L_i: [0.02, 0.03]}}}"
            )
        # too few grains across at the campaign's scale (diagnosis.size_scale 5): 9.4 mm is 4.4 across
        with pytest.raises(ConfigError, match=r"calibration.campaign_geometry.mine.L_i \(at diagnosis.size_scale"):
            as_run_sh_main(good, "calibration={campaign_geometry: {mine: {aspect_ratio: [1, 2], L_i: [0.02, 0.0094]}}}")


# -- the campaign through the tiny DAG ---------------------------------------------------------------


@pytest.fixture(scope="module")
def campaign_run(tmp_path_factory):
    """config/tiny_all.yaml with the campaign given on the command line beside its own column, only
    the campaign's targets built: (workflow folder, {rule: jobs})."""
    workdir = copy_workflow(tmp_path_factory.mktemp("campaign"))
    measured = f"measured={{tiny: data/test/tiny_quartz_a2.csv, lab: {CAMPAIGN_CSV}}}"
    # the BO routes search a little longer than tiny_all's plumbing minimum (4 points): a held-out
    # column is predicted only as well as the rest's optimum is found
    budgets = "calibration={budget: 12, n_initial: 6, gns_budget: 12, gns_n_initial: 6}"
    targets = ["results/campaign/lab/campaign.json", "results/report/campaign.md"]
    proc = snakemake(workdir, *targets, "--config", measured, budgets, configfile=TINY_ALL, timeout=900)
    return workdir, job_stats(proc.stderr)


@pytest.mark.slow
def test_the_dag_calibrates_a_campaign_as_one_parameter_set_by_each_route(campaign_run):
    workdir, jobs = campaign_run
    # the diagnosis reads the whole campaign; no single-column stage runs on it
    assert jobs.get("campaign_route") == 3 and jobs.get("diagnosis") == 1
    assert not any(rule.startswith(("calibrated_doe", "calibrated_contenders", "inverse")) for rule in jobs)
    result = CampaignResult.read(workdir / "results/campaign/lab/campaign.json")
    assert result.columns == ["campaign_a1", "campaign_a2", "campaign_a4"] and result.aspect_ratios == [1, 2, 4]
    model = json.loads((workdir / "results/calibrated/lab/model.json").read_text())
    for route in result.routes:
        assert route.model == model["model"] and route.parameter_names == model["parameters"]
        assert list(route.optimum.parameters) == model["parameters"] and route.optimum.columns == result.columns
        assert all(low <= v <= high for v, (low, high) in zip(route.optimum.theta, model["bounds"]))
        # one parameter set, validated on every column on >= 4 packings of their own
        assert [len(v.seeds) for v in route.validations] == [4, 4, 4]
        assert all(v.parameters == route.optimum.parameters and v.n_ran == 4 for v in route.validations)
        assert route.mse == pytest.approx(np.mean([v.mse for v in route.validations]))  # equal stated noise
        # each column from the others: calibrated on the other two, run on it
        assert [h.column for h in route.held_out] == result.columns
        for held in route.held_out:
            assert held.optimum.columns == [c for c in result.columns if c != held.column]
            assert held.validation.n_ran == 4 and held.scatter_bound > 0
    doe, bo, gns = result.routes
    assert doe.runs_per_column * 3 == doe.dem_runs == 48  # the CCD of 3 parameters + 1 replicate, on every column
    assert bo.runs_per_column * 3 == bo.dem_runs == 3 * 12  # calibration.budget points, one run per column
    # the GNS's dataset (calibration.gns_cases) cycles through the columns: an added column costs
    # it no DEM run before its validation
    assert gns.route.startswith("BO on the campaign's GNS") and gns.dem_runs == 3 and gns.runs_per_column == 0
    assert "leave none for another column" in gns.added_column_why  # 3 cases, 3 columns
    # its calibration's time holds its dataset's runs and its training beside its search
    assert 0 < gns.surrogate_seconds < gns.seconds
    runs = sorted((workdir / "results/dem/campaign_lab/trajectories").glob("*.h5"))
    geometries = sorted(round(float(read_attrs(p)["H_i"]) / float(read_attrs(p)["L_i"]), 6) for p in runs)
    assert geometries == [1.0, 2.0, 4.0]
    # the answer is the route that predicts held-out columns best, at its optimum on all of them
    best = min(result.routes, key=lambda r: r.held_out_mse)
    assert result.answer == best.route
    assert best.held_out_mse == pytest.approx(np.mean([h.validation.mse for h in best.held_out]))


@pytest.mark.slow
def test_each_column_predicted_from_the_others_lies_within_its_packing_scatter(campaign_run):
    """The hidden truth is in the model's reach, so the answer's route, calibrated on two columns,
    predicts the third as well as the packing scatter lets any parameter set: within SCATTER_LEVEL
    times the miss the truth itself would show. A prediction at the base model's or at a wrong
    column's curve misses by many times that."""
    workdir, _ = campaign_run
    result = CampaignResult.read(workdir / "results/campaign/lab/campaign.json")
    answer = result.answer_route
    for held in answer.held_out:
        assert held.within_scatter, (held.column, held.validation.mse, held.scatter_bound, held.optimum.parameters)
    # the bound is not loose enough to let any curve through: the a = 1 prediction set against the
    # a = 4 column misses by far more than that column's bound
    a1, a4 = answer.held_out[0], answer.held_out[2]
    measured = read_measured(CAMPAIGN_CSV)["campaign_a4"].runout
    assert np.mean((np.array(a1.validation.mean) - measured) ** 2) > 10 * a4.scatter_bound


@pytest.mark.slow
def test_the_report_shows_every_column_each_route_and_the_cost_per_column(campaign_run):
    workdir, _ = campaign_run
    section = (workdir / "results/report/campaign.md").read_text()
    result = CampaignResult.read(workdir / "results/campaign/lab/campaign.json")
    assert "## lab" in section and "**The answer:**" in section
    for route in result.routes:
        assert section.count(f"| {route.route} | campaign_a") == 3  # one held-out row per column
        assert f"{route.runs_per_column:.0f} runs" in section
        assert f"- {route.route}: calibration {route.dem_runs} DEM runs" in section  # how its cost is counted
    assert "of them its dataset's runs and its training" in section  # the GNS route's
    figure = workdir / "results/campaign/lab/campaign.png"
    assert figure.stat().st_size > 10_000 and "(../campaign/lab/campaign.png)" in section
    for route in ("doe", "bayesopt"):
        assert (workdir / f"results/campaign/lab/{route}.png").stat().st_size > 10_000


@pytest.mark.slow
def test_a_column_added_on_the_given_geometries_reruns_neither_the_dataset_nor_its_gns(tmp_path):
    """A campaign grows: its GNS dataset given by hand (calibration.campaign_geometry) and its model by
    the config (rolling resistance in its whole range), the dataset and its GNS made for a = 1 and 2
    are not planned again when the a = 4 column joins; only the campaign's diagnosis and model record
    are. Another model in the config is another dataset."""
    workdir = copy_workflow(tmp_path)
    lines = CAMPAIGN_CSV.read_text().splitlines()
    csv = workdir / "lab.csv"
    csv.write_text("\n".join(line for line in lines if not line.startswith("campaign_a4")) + "\n")
    settings = [
        "--config",
        f"measured={{tiny: data/test/tiny_quartz_a2.csv, lab: {csv}}}",
        "calibration={model: rolling_resistance, box: full, "
        "campaign_geometry: {lab: {aspect_ratio: [1, 2, 4], L_i: [0.01], duration_over_tstar: 3}}}",
    ]
    targets = ["results/gns/campaign_lab/train/model_best.pt", "results/calibrated/lab/model.json"]
    # the GNS alone first: with its model fixed by the config, its dataset needs no diagnosis
    first = job_stats(snakemake(workdir, targets[0], *settings, configfile=TINY_ALL, timeout=600).stderr)
    assert first.get("dem_run") == 3 and first.get("gns_train") == 1 and "diagnosis" not in first
    csv.write_text("\n".join(lines) + "\n")  # the a = 4 column joins the campaign
    # Snakemake's plan: a job whose input a planned job rewrites (the diagnosis' model.json) is
    # planned too, so the dataset and its GNS would show here if they read it
    second = snakemake(workdir, *targets, *settings, "-n", configfile=TINY_ALL, timeout=600)
    assert set(job_stats(second.stdout + second.stderr)) == {"calibrated_model", "diagnosis", "diagnosis_library"}
    auto = [*settings[:2], settings[2].replace("model: rolling_resistance", "model: auto")]
    planned = snakemake(workdir, *targets, *auto, "-n", configfile=TINY_ALL, timeout=600)
    planned = job_stats(planned.stdout + planned.stderr)  # under auto the dataset follows the diagnosis
    assert planned.get("diagnosis") == 1 and planned.get("dem_run") == 3 and planned.get("gns_train") == 1
    cohesion = [*settings[:2], settings[2].replace("model: rolling_resistance", "model: cohesion")]
    planned = snakemake(workdir, *targets, *cohesion, "-n", configfile=TINY_ALL, timeout=600)
    planned = job_stats(planned.stdout + planned.stderr)
    assert planned.get("dem_run") == 3 and planned.get("gns_train") == 1


# -- a campaign made by another solver ----------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("liggghts") is None, reason="LIGGGHTS is not installed (run.sh installs it)")
def test_a_cohesive_campaign_made_by_liggghts_shows_which_column_does_not_transfer(tmp_path):
    """A campaign made by another solver (LIGGGHTS: Hertz with SJKR cohesion, its own packing, the
    lab's connected-front reading, noise 0.05 in L*) of a cohesive material, Bond number 29.6: the BO
    on DEM calibrates the cohesion model on all three columns, reading each the lab's way. Predicted
    from the others, the short columns lie within their packing scatter; the tall one, whose runout
    hangs on a cohesion the short columns barely feel, misses by far more than its own: the
    leave-one-out table says which column a campaign cannot do without."""
    cohesion = get_mechanisms(["cohesion"])[0]
    truth = HiddenTruth(0.61, 0.52, "cohesion", 29.6, 10165)
    columns = synthetic_columns(
        "quartz", 0.01, (1.0, 2.0, 4.0), times=(0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0), profile_step_diameters=None
    )
    settings = SimulationSettings(size_scale=4)
    measured, _ = liggghts_measurement(truth, columns, [cohesion], settings, 0.05, 0.001, np.random.default_rng(3))
    assert {c.runout_method for c in measured} == {LAB_RUNOUT.method}  # read as the lab's images are
    runner = CampaignRunner(Campaign("lab", tuple(measured)), Model(cohesion), settings, RunoutMethod(), None)
    section = {"budget": 12, "n_initial": 6, "seed": 0, "validation_packings": 4}
    result = run_campaign_route(runner, "bayesopt", tmp_path / "bo.json", tmp_path / "bo.png", section)
    short, tall = result.held_out[:2], result.held_out[2]
    assert all(h.within_scatter for h in short), [(h.validation.mse, h.scatter_bound) for h in short]
    assert tall.validation.mse > 10 * tall.scatter_bound, (tall.validation.mse, tall.scatter_bound)
    assert result.held_out_mse > 10 * result.mse  # the fit on all three hides it; the held-out check does not
