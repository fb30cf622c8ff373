"""The whole DAG of config/tiny_all.yaml end to end: every stage runs for real, at its smallest size.

One run for the module (a copy of the workflow, tests/test_workflow.py's machinery): DEM and the
dataset, the GNS (training, rollout, evaluation), the runout-method study, the DoE, the inverse
design (GNS, DEM validation, Bayesian optimisation on DEM, comparison, parameter recovery), the
diagnosis, the calibrated model (its DoE, BO and GNS routes, every route validated on 3 packings,
the finer-scale transfer, predictions), the scale ladder (one size_scale, one packing), the ParaView
export and the report. The measured column
is data/test/tiny_quartz_a2.csv, a synthetic curve in the geometry of the config's one dataset.
The fixture gives the column as a user brings one (README "Calibrate your own column"): a CSV of
a material of its own written outside the workflow, on the command line; config/tiny_all.yaml's
dataset takes that column's material and geometry (`measured: tiny`), so the DAG builds it for the
CSV. The checks are of plumbing and sanity (files written, numbers finite and in range, every stage in
the report), not of accuracy: the GNS trains 200 steps on 3 columns of 77 grains.

Cost: 110 jobs; the 105 before the scale ladder took 212 s in all (their benchmark files; most of
it Python start-up per job, the longest chain 46 s). Measured at --cores 1 on the 2-core box beside
another engineer's busy process: 218 s, and 290-340 s under heavier load; at --cores 2 about half
(the DAG list-scheduled with those job times: 107 s), plus 7 s for the checks. With the ladder, at
--cores 1 and nice 19 beside a busy benchmark: 345 s. E2E_CORES sets the cores (default 2).
"""

import ast
import csv
import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from calibration.calibrated_result import CalibratedResult
from dem.trajectory import read_attrs, read_trajectory
from gns.dataset import load_dataset_metadata
from pipeline.calibrated_section import answer_score
from pipeline.shipped import freeze
from tests.conftest import OWN_MATERIAL
from tests.test_workflow import snakemake

pytestmark = pytest.mark.slow
CONFIG = "config/tiny_all.yaml"
NAME, DATASET = "tiny", "tiny_column"  # the measured entry and the dataset whose GNS calibrates it
MODEL_DATASET = f"calibrated_{NAME}"
PAIR = "rolling_resistance+sidewall_friction"  # config/tiny_all.yaml's contender_pairs
CORES = int(os.environ.get("E2E_CORES", "2"))
PNG = b"\x89PNG\r\n\x1a\n"
# Jobs per rule of the tiny DAG: 5 dataset cases + 10 DoE runs (3 x 3 levels + 1 centre replicate)
# + 1 scale-ladder run + the calibrated model's 3 cases, all through the DEM rules; one GNS on the dataset (for the
# recovery study) and one on the calibrated model's 3 cases and the dataset's 5 (calibration.gns_shared: it runs both
# models' inverse design); 9 routes of the calibrated model validated; 5 trajectories exported (the shared GNS's
# rollout + its DEM run, 2 DoE validations, the inverse validation).
EXPECTED_JOBS = {
    "dem_deck": 19,
    "dem_packing": 19,
    "dem_run": 19,
    "dem_figure": 5,
    "dataset": 2,
    "dataset_summary": 1,
    "dataset_section": 1,
    "gns_train": 2,
    "gns_rollout": 2,
    "gns_evaluate": 2,
    "gns_section": 1,
    "runout_methods": 1,
    "doe_design": 1,
    "doe_analyse": 1,
    "doe_validate": 2,
    "doe_section": 1,
    "inverse_start": 1,
    "inverse_design": 1,
    "inverse_validate": 1,
    "inverse_bayesopt": 1,
    "inverse_compare": 1,
    "inverse_recovery": 1,
    "inverse_section": 1,
    "diagnosis_library": 1,
    "diagnosis": 1,
    "diagnosis_section": 1,
    "calibrated_contenders": 1,
    "calibrated_model": 1,
    "calibrated_doe": 1,
    "calibrated_bayesopt": 1,
    "calibrated_inverse": 1,
    "calibrated_validate": 10,
    "calibrated": 1,
    "calibrated_section": 1,
    "scale_ladder": 1,
    "export_vtk": 5,
    "export_calibrated_vtk": 1,
    "report": 1,
    "all": 1,
}
CALIBRATED_ROUTES = {
    "diagnosis-base",
    "diagnosis-model",
    "base-inverse",
    "base-bayesopt",
    "base-doe-eq9",
    "base-doe-quadratic",
    "model-inverse",
    "model-doe",
    "model-doe-ff",
    "model-bayesopt",
}
REPORT_SECTIONS = [  # in report order: the answer first
    "The calibrated model",
    "DEM datasets",
    "Graph-network simulator",
    "Calibration by design of experiments (DoE)",
    "Inverse design through the GNS and the comparison with DoE",
    "What the simulation gets wrong: diagnosis",
    "How the runout is read: the methods compared",
    "How the runout depends on grain size: the scale ladder",
    "Time per stage",
]
# stages in the time table (the report job writes its own benchmark after the table)
STAGES = ["calibrated", "dataset", "dem", "diagnosis", "doe", "export", "gns", "inverse", "runout", "scale_ladder"]


@pytest.fixture(scope="module")
def run(tiny_all_run):
    """The finished tiny DAG (tests/conftest.py, one run per session): (workflow folder, {rule:
    jobs} Snakemake planned, wall seconds, its --config arguments)."""
    return tiny_all_run


@pytest.fixture(scope="module")
def results(run):
    return run[0] / "results"


def load(path: Path):
    """A JSON file, strictly: NaN and Infinity are not JSON (a value that may be absent is null)."""

    def refuse(token):
        raise ValueError(f"{path}: {token} in JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def flatten(values):
    for v in values:
        if isinstance(v, list | tuple):
            yield from flatten(v)
        else:
            yield v


def finite(*values) -> bool:
    """Every number in values (nested lists too) is a finite number, none null."""
    flat = list(flatten(values))
    return bool(flat) and all(isinstance(v, int | float) and math.isfinite(v) for v in flat)


def within(params: dict, names, bounds) -> bool:
    return all(low - 1e-9 <= params[n] <= high + 1e-9 for n, (low, high) in zip(names, bounds))


def assert_png(path: Path):
    assert path.is_file(), path
    head = path.read_bytes()[:8]
    assert head == PNG and path.stat().st_size > 10_000, f"{path}: not a drawn PNG ({path.stat().st_size} bytes)"


def assert_trajectory(path: Path, n_frames: int | None = None):
    trajectory = read_trajectory(path)
    assert trajectory.positions.ndim == 3 and np.isfinite(trajectory.positions).all(), path
    if n_frames is not None:
        assert trajectory.n_frames == n_frames, path
    return trajectory


# -- the DAG ----------------------------------------------------------------------------------------
def test_every_stage_ran_each_planned_job_and_nothing_is_left_to_do(run):
    workdir, stats, _, own = run
    assert {rule: stats.get(rule, 0) for rule in EXPECTED_JOBS} == EXPECTED_JOBS
    summary = snakemake(workdir, "--summary", *own, configfile=CONFIG, cores=CORES).stdout
    rows = [line.split("\t") for line in summary.strip().splitlines()[1:]]
    assert len(rows) > 100
    stale = [(r[0], r[4], r[5]) for r in rows if r[4] != "ok" or r[5] != "no update"]
    assert not stale, stale  # every declared output exists and a rerun would do nothing
    # the processes a job makes its DEM runs in (dem.workers) change no result: nothing to rerun
    other = snakemake(workdir, "--summary", *own, "dem={workers: 1}", configfile=CONFIG, cores=CORES).stdout
    assert [line.split("\t")[5] for line in other.strip().splitlines()[1:]] == ["no update"] * len(rows)
    for output, *_ in rows:  # every figure a rule declares is drawn
        if output.endswith(".png"):
            assert_png(workdir / output)
    results = workdir / "results"
    for rule, count in stats.items():  # every job left its benchmark (the report's time table)
        if rule != "all":
            found = list(results.glob(f"benchmarks/*/{rule}.tsv")) + list(results.glob(f"benchmarks/*/{rule}/**/*.tsv"))
            assert len(found) == count, rule


def test_every_json_is_strict_json_and_every_trajectory_finite(results):
    jsons = [p for p in results.rglob("*.json") if "/logs/" not in str(p)]
    assert len(jsons) > 30
    for path in jsons:
        load(path)
    trajectories = [
        p
        for p in results.rglob("*.h5")
        if "/packings/" not in str(p) and not p.name.startswith(".") and "/logs/" not in str(p)
    ]
    # 5 dataset cases, 10 DoE runs, 2 DoE validations, 3 cases of the calibrated model's GNS, 2 GNS
    # rollouts, the inverse design's start and validation runs, the best BO run, the scale-ladder run
    assert len(trajectories) == 26
    for path in trajectories:
        assert_trajectory(path)


# -- DEM and dataset ------------------------------------------------------------------------------------
def test_dem_and_dataset(results, run):
    config = yaml.safe_load((run[0] / CONFIG).read_text())
    spec = config["datasets"][DATASET]
    meta = load_dataset_metadata(results / "datasets" / DATASET / "metadata.json")
    assert {k: len(v) for k, v in meta["splits"].items()} == {"train": 3, "valid": 1, "test": 1}
    assert meta["dt_frame"] == pytest.approx(spec["output_interval"])
    assert min(meta["velocity_std"]) > 0 and min(meta["acceleration_std"]) > 0
    cases = (results / "datasets" / DATASET / "cases.csv").read_text().splitlines()
    assert len(cases) == spec["n_cases"] + 1 and "final_L_star" in cases[0]
    n_frames = None
    for k in range(spec["n_cases"]):
        path = results / "dem" / DATASET / "trajectories" / f"case_{k:03d}.h5"
        attrs = read_attrs(path)
        assert attrs["engine"] == "builtin" and attrs["material"] == OWN_MATERIAL["name"] and attrs["aspect_ratio"] == 2
        assert attrs["material_density"] == OWN_MATERIAL["density"], path  # the CSV's material, not the table's
        n_frames = assert_trajectory(path, n_frames).n_frames
        simulated = (n_frames - 1) * attrs["dt_frame"]
        assert simulated == pytest.approx(spec["duration_over_tstar"] * attrs["t_star"], abs=attrs["dt_frame"])


def test_own_column_got_its_dataset_calibration_diagnosis_and_report(results):
    """The CSV's column (a material of its own): its dataset, GNS, inverse design, DoE, diagnosis,
    calibrated model and report section, each of that material."""
    meta = load_dataset_metadata(results / "datasets" / DATASET / "metadata.json")
    assert meta["materials"] == [OWN_MATERIAL["name"]]
    for trajectory in ("inverse/tiny/validation.h5", "doe/tiny/validation/eq9.h5"):
        attrs = read_attrs(results / trajectory)
        assert (attrs["material"], attrs["material_solid_fraction"]) == (OWN_MATERIAL["name"], 0.6), trajectory
    assert load(results / "diagnosis" / NAME / "diagnosis.json")["columns"][0]["material"] == OWN_MATERIAL["name"]
    assert load(results / "calibrated" / NAME / "calibrated.json")["answer"]
    assert f"{NAME}: {OWN_MATERIAL['name']}, a = 2" in (results / "report.md").read_text()


# -- GNS ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dataset, steps", [(DATASET, 200), (MODEL_DATASET, 50)])
def test_gns_trained_rolled_out_and_scored(results, dataset, steps):
    gns = results / "gns" / dataset
    assert (gns / "train" / "model_best.pt").stat().st_size > 1000
    metrics = np.genfromtxt(gns / "train" / "metrics.csv", delimiter=",", names=True)
    assert metrics["step"][-1] == steps and np.isfinite(metrics["train_loss"]).all()
    validated = np.isfinite(metrics["valid_one_step_loss"])
    assert validated.any() and np.isfinite(metrics["valid_runout_mse"][validated]).all()
    summary = load(gns / "evaluation" / "summary.json")
    assert summary["n_cases"] == 1 and summary["n_failed"] == 0
    assert finite(summary["runout_mse"], summary["position_mse_m2"], summary["position_mse_d2"])
    (case,) = summary["cases"]
    rollout = assert_trajectory(results.parent / case["gns"])
    assert read_attrs(results.parent / case["gns"])["engine"] == "gns"
    assert rollout.n_frames == read_trajectory(results.parent / case["dem"]).n_frames


def test_one_gns_trained_on_both_models_runs_the_base_models_inverse_design(results):
    """calibration.gns_shared: the model's GNS dataset holds the base dataset's runs too, its
    mechanism off (parameter_off, the model's), and the base model's inverse design ran on it."""
    meta = load_dataset_metadata(results / "datasets" / MODEL_DATASET / "metadata.json")
    base = load_dataset_metadata(results / "datasets" / DATASET / "metadata.json")
    model = load(results / "calibrated" / NAME / "model.json")
    for split, paths in base["splits"].items():
        assert set(paths) <= set(meta["splits"][split]), split
    assert meta["n_cases"]["train"] == base["n_cases"]["train"] + 1
    assert set(meta["parameter_off"]) == set(model["parameters"][2:])
    assert list(meta["parameter_ranges"])[: len(model["parameters"])] == model["parameters"]
    log = (results / "logs" / "inverse" / "inverse_design" / f"{NAME}.log").read_text()
    held = re.search(r"through the GNS of dataset (\w+); held off (\{.*\}), tied (\{.*\})", log)
    assert held and held[1] == MODEL_DATASET, log[-2000:]
    off = {**ast.literal_eval(held[2]), **ast.literal_eval(held[3])}  # every mechanism off: held, or tied to mu
    assert off == meta["parameter_off"]


def test_runout_methods(results):
    study = load(results / "runout" / "methods.json")
    assert study["configured"]["method"] == "dense_front_reached"
    (case,) = load(results / "gns" / MODEL_DATASET / "evaluation" / "summary.json")["cases"]
    test_case = Path(case["dem"]).stem  # the GNS's test case (its GNS_DATASETS: the shared one), the DoE centre
    assert set(study["cases"]) == {f"{MODEL_DATASET} {test_case}", f"DoE {NAME} centre"}
    assert set(study["mean"]) == {"connected_front", "dense_front", "connected_front_reached", "dense_front_reached"}
    for name, mean in study["mean"].items():
        assert finite(mean["scatter_mean"], mean["flicker"], mean["rerun_mse"], mean["gns_mse"]), name
        # the runs last 2 t*: the stopping phase (t/t* > 2.5) is not reached and is left out
        assert set(mean["scatter_by_phase"]) == {"free_fall", "spreading"}, name
        assert finite(list(mean["scatter_by_phase"].values())), name


def test_scale_ladder(results):
    """config/tiny_all.yaml's ladder: size_scale 4, one packing, 1 t*, read by the configured method."""
    summary = load(results / "scale_ladder" / "summary.json")
    assert summary["runout"]["method"] == "dense_front_reached" and summary["case"]["aspect_ratio"] == 2
    (entry,) = summary["by_size_scale"].values()
    assert entry["size_scale"] == 4 and entry["seeds"] == [0] and entry["final_t_over_tstar"] == pytest.approx(1.0)
    assert set(entry["runout_at"]) == {"1"} and entry["runout_at"]["1"]["std"] is None  # one packing: no scatter
    run = results / "dem" / "scale_ladder" / "trajectories" / "scale4_packing0.h5"
    assert entry["n_particles"] == read_trajectory(run).n_particles
    assert finite(entry["final_runout"]["mean"], entry["final_height_over_H_i"]["mean"], entry["settle_s"]["mean"])
    assert entry["collapse_s"]["per_packing"] == [read_attrs(run)["wall_time_s"]]


# -- DoE -----------------------------------------------------------------------------------------------
def test_doe(results):
    doe = results / "doe" / NAME
    analysis = load(doe / "analysis.json")
    assert analysis["n_runs"] == analysis["n_fitted"] == 10 and analysis["failed"] == {}
    assert finite(analysis["best_run"]["mse"], analysis["pure_error"]["std"])
    for model in ("eq9", "quadratic"):
        fit = analysis["models"][model]
        assert 0 <= fit["r_squared"] <= 1 and finite(fit["rmse"]), model
        assert finite([c["estimate"] for c in fit["coefficients"]]), model
        assert finite([(e["F"], e["p_value"]) for e in fit["effects"]]), model
        optimum = fit["optimum"]
        assert within(optimum["natural"], ["friction", "restitution"], [[0.3, 0.9], [0.3, 0.9]]), model
        assert finite(optimum["predicted"]), model
        validation = assert_trajectory(doe / "validation" / f"{model}.h5")
        assert read_attrs(doe / "validation" / f"{model}.h5")["friction"] == pytest.approx(
            optimum["natural"]["friction"]
        )
        assert validation.n_frames > 10
    responses = (doe / "responses.csv").read_text().splitlines()
    assert len(responses) == 11


# -- inverse design, validation, Bayesian optimisation, comparison, recovery ----------------------------------
def test_inverse_design_and_its_validation(results):
    inverse = load(results / "inverse" / NAME / "inverse.json")
    assert inverse["names"] == ["friction", "restitution"] and len(inverse["starts"]) == 1
    assert inverse["starts"][0]["n_iterations"] <= 2
    assert finite(inverse["best_value"], inverse["best_runout"], inverse["start_runout"], inverse["model_error_std"])
    assert within(dict(zip(inverse["names"], inverse["best_params"])), inverse["names"], inverse["bounds"])
    assert len(inverse["best_runout"]) == 7  # the measured points
    assert finite([(p["value"], p["std"], p["low"], p["high"]) for p in inverse["posterior"]["parameters"]])
    assert inverse["geometry"]["distance"] == 0  # the dataset holds the measured column
    assert inverse["landscape"] is None  # inverse.landscape_levels 0: none drawn (documented as null)
    validation = read_attrs(results / "inverse" / NAME / "validation.h5")
    assert validation["friction"] == pytest.approx(inverse["best_params"][0], rel=1e-6)
    assert_trajectory(results / "inverse" / NAME / "start.h5")


def test_bayesopt_on_dem(results):
    bo = load(results / "inverse" / NAME / "bayesopt.json")
    assert bo["dem_runs"] == len(bo["values"]) == 7 and bo["failed"] == []  # 6 initial runs, 1 chosen by EI
    assert finite(bo["values"]) and bo["best_value"] == min(bo["values"])
    assert within(dict(zip(bo["names"], bo["best_params"])), bo["names"], [[0.3, 0.9], [0.3, 0.9]])


def test_comparison_of_routes(results):
    with open(results / "inverse" / NAME / "comparison.csv", newline="") as f:
        table = list(csv.DictReader(f))
    methods = {row["method"] for row in table}
    assert methods == {"start point", "GNS inverse design", "DoE (eq9)", "DoE (quadratic)", "BO on DEM"}
    for row in table:
        assert float(row["wall_s"]) > 0 and int(row["dem_runs"]) >= 1, row
        if row["stage"] == "offline":  # the GNS's dataset and training: no optimum to validate
            assert row["validated_mse"] == "" and row["friction"] == "", row
        else:
            mse, mu, e = (float(row[k]) for k in ("validated_mse", "friction", "restitution"))
            assert finite(mse, mu, e) and mse >= 0 and 0.3 - 1e-9 <= mu <= 0.9 + 1e-9, row


def test_parameter_recovery(results):
    recovery = load(results / "inverse_recovery" / DATASET / "recovery.json")
    assert recovery["n_cases"] == len(recovery["cases"]) == 1 and recovery["packings"] == 2
    assert finite(recovery["mu_error_mean"], recovery["packing_std"], recovery["model_error_std"])
    (case,) = recovery["cases"]
    assert finite(case["truth"], case["estimate"])
    assert all(low - 1e-9 <= x <= high + 1e-9 for x, (low, high) in zip(case["estimate"], recovery["bounds"]))


# -- diagnosis -------------------------------------------------------------------------------------------
def test_diagnosis(results):
    diagnosis = load(results / "diagnosis" / NAME / "diagnosis.json")
    assert diagnosis["cause"] in ("none", "rolling_resistance") and diagnosis["verdict"]
    assert diagnosis["best_candidate"] == "rolling_resistance"
    assert (diagnosis["extended"] is None) == (diagnosis["cause"] == "none")  # null: no cause named
    assert finite(list(diagnosis["base"]["emulator"]["parameters"].values()))
    assert finite(list(diagnosis["candidates"]["rolling_resistance"]["emulator"]["parameters"].values()))
    assert finite(diagnosis["residuals"]["chi2"]) and 0 <= diagnosis["residuals"]["p_value"] <= 1
    errors = diagnosis["errors"]
    assert finite([errors[k][w] for k in ("fit_mse", "heldout_mse") for w in ("before", "after")])
    assert diagnosis["observables"]["measured"] == pytest.approx([0.06, 0.16, 0.36, 0.6, 0.85, 1.2, 1.5])


# -- the calibrated model ------------------------------------------------------------------------------
def test_the_contenders_are_predicted_across_a_before_the_model_is_chosen(results):
    """Under auto, every model the diagnosis scored in the DEM (base, rolling resistance) and the pair
    of config/tiny_all.yaml (rolling resistance + side-wall friction, fitted here in the DEM from
    rolling resistance's fit) are predicted at a = 1 and 3, by real DEM runs, and held against the
    quasi-2D law; model.json says it was and why, and the report shows them side by side."""
    calibrated = results / "calibrated" / NAME
    contenders = load(calibrated / "contenders.json")
    diagnosis = load(results / "diagnosis" / NAME / "diagnosis.json")
    assert [c["model"] for c in contenders["contenders"]] == ["base", "rolling_resistance", PAIR]
    for c in contenders["contenders"]:
        if c["model"] != PAIR:
            scored = diagnosis["base"] if c["model"] == "base" else diagnosis["candidates"][c["model"]]
            assert c["parameters"] == pytest.approx(scored["dem"]["parameters"]) and c["bic"] == scored["dem"]["bic"]
        scaling = c["scaling"]
        assert scaling["aspect_ratios"] == [1.0, 3.0] and len(c["runout_each"]) == 1  # scaling_packings 1
        assert scaling["final_runout"] == pytest.approx(c["runout_each"][0])
        # a column of a = 3 runs out further than one of a = 1, as every granular column does
        assert 0 < scaling["final_runout"][0] < scaling["final_runout"][1]
        ratios = [math.log(v / law) for v, law in zip(scaling["final_runout"], scaling["runout_law"])]
        assert c["law_chi2"] == pytest.approx(sum((r / contenders["law_log_std"]) ** 2 for r in ratios))
        assert c["combined"] == pytest.approx(c["bic"] + c["law_chi2"] + c["transfer_chi2"])
        # each candidate's curve at the diagnosis' grain size and the target's, on the same packing
        shift = c["grain_shift"]
        if c["model"] == "base":
            assert shift is None and c["transfer_chi2"] == 0
        else:
            assert shift["size_scales"] == [4, 3.5] and shift["seeds"] == [5001] and c["transfer_chi2"] == shift["chi2"]
            assert shift["shift_mse"] >= 0 and finite(shift["coarse_mean"], shift["fine_mean"])
    # the pair: from rolling resistance's fit (side-wall friction off), a star of 9 runs and one step
    # on one packing of its own, then its BIC on the diagnosis' one packing, against the same noise
    pair = contenders["contenders"][2]
    fit = pair["pair_fit"]
    assert fit["start"] == "rolling_resistance" and fit["dem_runs"] == 9 + 1 + 1 and fit["packings"] == [0]
    assert fit["fit_mse"] <= fit["start_mse"] and pair["parameters"] == fit["parameters"]
    n_data = diagnosis["candidates"]["rolling_resistance"]["dem"]["n_data"]
    assert pair["bic"] == pytest.approx(fit["chi2"] + 4 * math.log(n_data))
    # the base is never chosen; the lowest combined score of the candidates is
    candidates = [c for c in contenders["contenders"][1:] if not c["switched_off"]]
    assert contenders["chosen"] == min(candidates, key=lambda c: c["combined"])["model"]
    assert contenders["L_i"] == pytest.approx(0.01)
    model = load(calibrated / "model.json")
    assert model["model"] == contenders["chosen"] and model["scaling_check"] is True
    assert "Judged by its predictions across a too" in model["why"] or "judged by what each contender" in model["why"]
    assert (calibrated / "contenders.png").read_bytes().startswith(PNG)
    section = (results / "report" / "calibrated.md").read_text()
    assert "**The contenders, judged by what they predict.**" in section and "contenders.png" in section
    assert f"{PAIR} from rolling_resistance's fit, runout MSE" in section
    assert "**Plausibility.** rolling_friction = " in section and "as 'glass' states none" in section


def test_calibrated_model_routes_and_validations(results):
    calibrated = results / "calibrated" / NAME
    model = load(calibrated / "model.json")
    # the contenders' choice: rolling resistance, or its pair with side-wall friction (4 parameters)
    chosen = model["model"]
    assert chosen in ("rolling_resistance", PAIR)
    names, bounds = model["parameters"], model["bounds"]
    assert names == ["friction", "restitution", "rolling_friction"] + (["sidewall_friction"] if chosen == PAIR else [])
    p = len(names)
    for route in ("doe", "bayesopt"):
        result = load(calibrated / f"{route}.json")
        assert within(result["optimum"], names, bounds) and finite(list(result["optimum"].values())), route
    assert load(calibrated / "doe.json")["dem_runs"] == 2**p + 2 * p + 1 + 1  # corners, faces, centre, replicate
    assert load(calibrated / "bayesopt.json")["dem_runs"] == 4
    gns = load(calibrated / "inverse.json")
    assert gns["names"] == names and finite(gns["best_params"], gns["best_value"])
    assert within(dict(zip(names, gns["best_params"])), names, bounds)
    # 3 DEM runs cannot fit a plane in 3 or more parameters: the GNS's response is not checked, and says so
    sensitivity = gns["sensitivity"]
    assert sensitivity["parameters"] == [] and "not checked" in sensitivity["why"]
    assert len(sensitivity["dem"]["last"]) == 3 and finite(sensitivity["gns"]["last"])
    assert (calibrated / "inverse_sensitivity.png").stat().st_size > 10_000
    validations = {p.stem: load(p) for p in (calibrated / "validation").glob("*.json")}
    assert set(validations) == CALIBRATED_ROUTES
    for key, v in validations.items():
        assert v["key"] == key and len(v["curves"]) == 3 and v["failed"] == {}, key
        assert finite(v["mse"], v["mse_se"], v["mean"], v["curves"]) and v["mse"] >= 0, key
        assert within(v["parameters"], list(v["parameters"]), [bounds[names.index(n)] for n in v["parameters"]]), key
        assert v["model"] == ("base" if key.startswith(("base-", "diagnosis-base")) else chosen), key
    # the GNS route's 2 best distinct points ran by the DEM on 1 packing each, then at most one
    # correction step along the GNS's slopes (inverse.json records every point it rolled out); the
    # lowest of all was validated
    assert len(gns["evaluated"]["points"]) == len(gns["evaluated"]["runouts"]) >= 6
    confirmation = validations["model-inverse"]["extra"]["confirmation"]
    candidates, steps = confirmation["candidates"], confirmation["steps"]
    assert len(candidates) == 2 and len(steps) <= 1 and len(confirmation["predicted"]) == len(steps)
    assert [c["seeds"] for c in candidates + steps] == [[7001]] * (2 + len(steps))
    chosen = (candidates + steps)[confirmation["chosen"]]
    assert chosen["mse"] == min(c["mse"] for c in candidates + steps)
    assert validations["model-inverse"]["parameters"] == chosen["parameters"]
    values = confirmation["surrogate_values"]
    assert confirmation["dem_runs"] == 2 + len(steps) and values == sorted(values)


def test_calibrated_answer_transfer_and_prediction(results):
    answer = load(results / "calibrated" / NAME / "calibrated.json")
    routes = {r["key"]: r for r in answer["routes"]}
    assert set(routes) == CALIBRATED_ROUTES
    p = len(answer["parameters"])
    model_routes = [r for r in routes.values() if r["model"] == answer["model"]]
    best = min(model_routes, key=lambda r: r["mse"])
    assert answer["validation_packings"] == 3
    # the routes within 2 SE of the best (paired) on a fourth packing; the lowest there is the answer
    scored = {r["key"]: r for r in answer["runoff"]}
    assert set(scored) <= {r["key"] for r in model_routes}  # only the model's routes compete
    if len(scored) > 1:
        assert best["key"] in scored and answer["answer_packings"] == 4
        for key, r in scored.items():
            assert len(r["seeds"]) == 4 and r["curves"][:3] == routes[key]["curves"] and finite(r["mse"])
        assert answer["answer"] == min(scored.values(), key=lambda r: r["mse"])["route"]
    else:  # the best alone within its scatter: it is the answer
        assert answer["answer"] == best["route"] and answer["answer_packings"] == 3
    for r in routes.values():
        assert finite(r["versus_answer"]["mse_difference"], r["versus_answer"]["se"]), r["key"]
    # the GNS route against each DoE: the CCD (2^p + 2p + 1 + 1 runs) and the full factorial (3^p + 1)
    versus = {v["doe_key"]: v for v in answer["gns_vs_doe"]}
    assert set(versus) == {"model-doe", "model-doe-ff"}
    assert versus["model-doe"]["doe_dem_runs"] == 2**p + 2 * p + 2
    assert versus["model-doe-ff"]["doe_dem_runs"] == 3**p + 1
    for v in versus.values():
        assert finite(v["mse_difference"], v["se"]) and v["gns_dem_runs"] == routes["model-inverse"]["dem_runs"]
        # on the runoff's packings where both ran there, else on the validation's
        both = {"model-inverse", v["doe_key"]} <= set(scored)
        mse = {k: (scored[k] if both else routes[k])["mse"] for k in ("model-inverse", v["doe_key"])}
        assert v["packings"] == (4 if both else 3)
        assert v["mse_difference"] == pytest.approx(mse["model-inverse"] - mse[v["doe_key"]])
    # glass states no plausible range of its own (calibration.plausible_ranges): the built-in one, said so
    plausible = answer["plausible"]
    assert (plausible[0]["parameter"], plausible[0]["range"]) == ("rolling_friction", [0.0, 0.3])
    assert [s["parameter"] for s in plausible] == answer["parameters"][2:]
    for stated in plausible:
        assert stated["source"].startswith("the default for dry grains of 0.1-1 mm, as 'glass' states none")
    # carried from size_scale 4 to the target 3.5 (the star: 2p + 1 points x 2 packings, then one step), then 3
    target, transfer = answer["target"], answer["transfer"]
    assert (target["coarse_size_scale"], target["size_scale"], target["coarse_runs"]) == (4, 3.5, (2 * p + 1) * 2)
    carried = target["validation"]
    assert carried["seeds"] == [5001, 5002, 5003] and finite(carried["mse"], carried["curves"])
    # the finer scale's parameters predicted from the two scales (target_scale.predict_finer), run there held out
    finer = target["finer"]
    assert finer["size_scale"] == 3 and finer["factor"] == pytest.approx(math.log(3.5 / 3) / math.log(4 / 3.5))
    start, star_centre = target["correction"]["candidates"][0], target["slopes"][0]
    assert finer["shift"] == pytest.approx((np.mean(start["curves"], axis=0) - star_centre["mean"]).tolist())
    assert list(finer["parameters"]) == answer["parameters"] and finite(finer["predicted_mse"])
    assert transfer["parameters"] == finer["parameters"] and answer["prediction_size_scale"] == 3.5
    assert transfer["size_scale"] == 3 and finite(transfer["mse"], transfer["curves"]) and transfer["failed"] == {}
    # what the project ships of such a result (pipeline.shipped.freeze): the answer at the target
    shipped = freeze(CalibratedResult.from_json(results / "calibrated" / NAME / "calibrated.json"))
    assert shipped.size_scale == 3.5 and shipped.route.endswith(", carried to size_scale 3.5")
    assert (shipped.parameters, shipped.curves) == (carried["parameters"], carried["curves"])
    assert shipped.mse == carried["mse"] and shipped.seeds == carried["seeds"]
    coarse_runs = answer_score(answer)["route"]["dem_runs"]
    assert shipped.dem_runs == coarse_runs + target["coarse_runs"] + target["target_runs"]
    prediction = answer["prediction"]
    assert prediction["aspect_ratios"] == [1.0, 3.0] and prediction["failed"] == {}
    assert finite(prediction["final_runout"], prediction["final_height"])
    assert prediction["final_runout"][0] < prediction["final_runout"][1]  # a taller column runs out further
    # intervals: the GNS inverse design's, and the diagnosis' of a model it fitted (one mechanism, not a pair)
    for key in ("intervals", "gns_intervals") if answer["model"] != PAIR else ("gns_intervals",):
        assert [q["name"] for q in answer[key]] == answer["parameters"]
        assert finite([(q["value"], q["low"], q["high"]) for q in answer[key]]), key
    assert answer["model"] != PAIR or answer["intervals"] is None


# -- export and report -------------------------------------------------------------------------------
def test_paraview_export(results):
    folders = [
        f"gns/{MODEL_DATASET}/rollouts",
        f"dem/{MODEL_DATASET}/trajectories",
        f"doe/{NAME}/validation/eq9",
        f"doe/{NAME}/validation/quadratic",
        f"inverse/{NAME}/validation",
        f"calibrated/{NAME}",
    ]
    for folder in folders:
        collections = list((results / "vtk" / folder).rglob("*.pvd"))
        assert collections, folder
        for pvd in collections:
            files = re.findall(r'file="([^"]+)"', pvd.read_text())
            assert len(files) > 10 and all((pvd.parent / f).stat().st_size > 0 for f in files), pvd


def test_report_names_every_stage(results):
    report = (results / "report.md").read_text()
    headings = re.findall(r"^## (.+)$", report, re.M)
    assert headings == REPORT_SECTIONS
    for title in REPORT_SECTIONS[:-1]:  # each stage's section has content, not only its heading
        body = report.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]
        assert len(body.strip()) > 100, title
    for stage in STAGES:  # the time table: every stage's jobs
        assert re.search(rf"^\| \*\*{stage}\*\* \| all \| \d+ \|", report, re.M), stage
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    assert len(links) > 10
    for link in links:
        assert_png(results / link)
    assert not re.search(r"\bnan\b", report, re.I)  # a value absent is said so, not printed as nan
