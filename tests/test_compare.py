"""DEM validation runs, Bayesian optimisation on DEM runs, and the comparison table/figures/report of
the calibration routes, on a tiny column (77 grains, builtin DEM)."""

from __future__ import annotations

import csv
import json
import math
import shutil

import numpy as np
import pytest

from calibration.compare import (
    BO_MAX_RUNS,
    ComparisonError,
    bayesopt_on_dem,
    case_like,
    comparison_routes,
    measured_case_fields,
    model_case_fields,
    read_table,
    write_table,
)
from calibration.objective import objective
from calibration.recovery import recovery_summary, recovery_targets, synthetic_measured
from dem.case import CollapseCase
from dem.collapse import simulate_collapse
from dem.runout import RunoutError, RunoutMethod
from dem.trajectory import read_attrs, read_trajectory, write_trajectory
from gns.dataset import build_dataset
from pipeline.inverse import run_bayesopt, run_comparison, run_dem_at, run_dem_point
from pipeline.inverse_section import report_section, write_section

RUNOUT = RunoutMethod()  # the config's default: every stage here reads L* by it


def tiny_case(friction, restitution, seed=0, **changes):
    """Quartz, a = 2, L_i = 1 cm, grains 4x coarse: 77 grains, 3 t* in 34 frames, under a second of DEM."""
    return CollapseCase(
        "quartz",
        L_i=0.01,
        aspect_ratio=2.0,
        friction=friction,
        restitution=restitution,
        size_scale=4,
        output_interval=0.004,
        duration_over_tstar=3.0,
        seed=seed,
        **changes,
    )


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A two-case "GNS dataset" of the tiny column and a synthetic measured CSV of the same column."""
    folder = tmp_path_factory.mktemp("compare")
    paths = []
    for k, (mu, e) in enumerate([(0.3, 0.3), (0.9, 0.9)]):
        paths.append(str(folder / f"case_{k}.h5"))
        write_trajectory(paths[-1], simulate_collapse(tiny_case(mu, e, seed=k)))
    build_dataset({"train": paths, "valid": paths[:1], "test": paths[1:]}, folder / "metadata.json", "tiny")
    truth = simulate_collapse(tiny_case(0.5, 0.6, seed=7))
    measured = synthetic_measured(
        truth, [0.5, 1.0, 1.5, 2.0, 2.5], 0.05, seed=0, name="tiny_target", packing_std=0.0, runout=RUNOUT
    )  # one run, its packing taken as the truth
    csv_path = folder / "measured.csv"
    with open(csv_path, "w") as handle:
        handle.write("column,material,aspect_ratio,L_i,kind,x,value,std\n")
        for t, value in zip(measured.t_over_tstar, measured.runout):
            handle.write(f"tiny_target,quartz,2.0,0.01,runout,{t},{value},0.05\n")
    return {"folder": folder, "metadata": str(folder / "metadata.json"), "measured": str(csv_path), "paths": paths}


def test_case_fields_keep_the_dem_model_and_let_wall_values_follow(tiny):
    attrs = read_attrs(tiny["paths"][0])
    fields = model_case_fields(attrs)
    assert fields["size_scale"] == 4 and fields["output_interval"] == pytest.approx(0.004)
    assert "friction_wall" not in fields and "seed" not in fields and "L_i" not in fields
    case = case_like(attrs, 0.7, 0.5, seed=3)
    assert case.resolved_friction_wall == 0.7 and case.resolved_restitution_wall == 0.5  # follow the new grain values
    assert (case.L_i, case.aspect_ratio, case.seed) == (0.01, 2.0, 3)
    apart = case_like(dict(attrs, friction_wall=0.2), 0.7, 0.5, seed=3)
    assert apart.resolved_friction_wall == 0.2  # a wall value set apart stays
    with_rolling = model_case_fields(simulate_collapse(tiny_case(0.5, 0.5, rolling_friction=0.1)).attrs)
    assert with_rolling["rolling_friction"] == 0.1  # mechanisms are part of the model
    assert measured_case_fields({"splits": {"train": tiny["paths"]}}, seed=5)["seed"] == 5


def test_dem_run_at_a_point_uses_the_measured_column_and_the_datasets_dem_model(tiny, tmp_path):
    summary = run_dem_point(
        tiny["measured"],
        tiny["metadata"],
        {"friction": 0.5, "restitution": 0.6},
        tmp_path / "run.h5",
        runout=RUNOUT.to_config(),
        seed=7,
        name="check",
    )
    trajectory = read_trajectory(tmp_path / "run.h5")
    assert trajectory.attrs["size_scale"] == 4 and trajectory.attrs["seed"] == 7
    assert (trajectory.attrs["friction"], trajectory.attrs["restitution"]) == (0.5, 0.6)
    # the measured curve is this very run plus noise of 0.05: the objective is near the noise variance
    assert summary["mse"] == pytest.approx(
        objective(
            trajectory,
            synthetic_measured(
                trajectory, [0.5, 1.0, 1.5, 2.0, 2.5], 0.05, seed=0, name="tiny_target", packing_std=0.0, runout=RUNOUT
            ),
            RUNOUT,
        ),
        rel=1e-9,
    )
    assert summary["mse"] < 4 * 0.05**2 and len(summary["runout"]) == 5


def test_the_start_and_validation_jobs_run_at_the_start_point_or_at_the_gns_optimum(tiny, tmp_path):
    inverse = _inverse_json(tmp_path / "inverse.json", [0.45, 0.65])
    name, params, summary = run_dem_at(
        tiny["measured"],
        tiny["metadata"],
        tmp_path / "validation.h5",
        runout=RUNOUT.to_config(),
        seed=1,
        result_path=inverse,
    )
    assert (name, params) == ("gns_optimum", {"friction": 0.45, "restitution": 0.65})
    assert (summary["friction"], summary["restitution"]) == (0.45, 0.65)
    name, params, _ = run_dem_at(
        tiny["measured"], tiny["metadata"], tmp_path / "start.h5", runout=RUNOUT.to_config(), seed=1, start=[0.55, 0.73]
    )
    assert (name, params) == ("start", {"friction": 0.55, "restitution": 0.73})
    assert read_trajectory(tmp_path / "start.h5").attrs["restitution"] == 0.73


@pytest.mark.skipif(shutil.which("liggghts") is None, reason="LIGGGHTS not installed (apt-get install liggghts)")
def test_a_validation_run_honours_the_configured_engine(tiny, tmp_path):
    """With dem.engine liggghts a validation runs in LIGGGHTS, as the DoE's and the dataset's runs do:
    the engine is recorded in the HDF5, and the run is not the builtin one."""
    summary = run_dem_point(
        tiny["measured"],
        tiny["metadata"],
        {"friction": 0.5, "restitution": 0.6},
        tmp_path / "liggghts.h5",
        runout=RUNOUT.to_config(),
        seed=7,
        name="check",
        dem={"engine": "liggghts", "solvers": {}},
    )
    trajectory = read_trajectory(tmp_path / "liggghts.h5")
    assert trajectory.attrs["engine"] == "liggghts" and "LIGGGHTS" in str(trajectory.attrs["engine_version"])
    builtin = run_dem_point(
        tiny["measured"],
        tiny["metadata"],
        {"friction": 0.5, "restitution": 0.6},
        tmp_path / "builtin.h5",
        runout=RUNOUT.to_config(),
        seed=7,
        name="check",
    )
    assert read_trajectory(tmp_path / "builtin.h5").attrs["engine"] == "builtin"
    assert summary["runout"] != builtin["runout"] and np.isfinite(summary["mse"])


def test_bayesian_optimisation_on_dem_runs_keeps_its_budget_and_its_best_run(tiny, tmp_path):
    out = tmp_path / "bo"
    data = run_bayesopt(
        tiny["measured"],
        tiny["metadata"],
        out / "bayesopt.json",
        out / "bayesopt.png",
        out / "best.h5",
        [(0.3, 0.9), (0.3, 0.9)],
        runout=RUNOUT.to_config(),
        budget=3,
        n_initial=2,
        seed=1,
    )
    assert data["dem_runs"] == 3 == len(data["values"]) and data["seconds"] > 0
    best = read_trajectory(out / "best.h5")
    assert [best.attrs["friction"], best.attrs["restitution"]] == pytest.approx(data["best_params"])
    assert data["best_value"] == pytest.approx(min(data["values"]))
    assert data["runout"] == RUNOUT.to_config()  # bayesopt.json states how it read L*
    assert (out / "bayesopt.png").stat().st_size > 1000
    with pytest.raises(ComparisonError, match=f"between 2 and {BO_MAX_RUNS} DEM runs"):
        bayesopt_on_dem(None, {}, [(0.3, 0.9)] * 2, RUNOUT, budget=21)


def _benchmark(path, seconds):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"s\th:m:s\tmax_rss\n{seconds}\t0:00:01\t10.0\n")
    return str(path)


def _bayesopt_json(path, runout):
    """A bayesopt.json of 12 DEM runs, best (0.6, 0.6) at 0.02, stating the runout method `runout`."""
    data = {
        "names": ["friction", "restitution"],
        "params": [[0.6, 0.6]],
        "values": [0.02],
        "seconds": [1.0],
        "best_params": [0.6, 0.6],
        "best_value": 0.02,
        "dem_runs": 12,
        "runout": runout,
    }
    path.write_text(json.dumps(data))
    return path


def _inverse_json(path, params, online_s=12.5, runout="default"):
    """The parts of an inverse.json the comparison and the report read; runout: the runout method
    it states ("default": RUNOUT's, None: none, as before the runout contract)."""
    parameters = [
        {"name": n, "value": v, "std": 0.05, "low": v - 0.1, "high": v + 0.1, "identifiable": True, "why": ""}
        for n, v in zip(["friction", "restitution"], params)
    ]
    parameters[1].update(identifiable=False, low=0.3, high=0.9, why="the measured runout hardly changes with it")
    data = {
        "measured": "tiny_target",
        "names": ["friction", "restitution"],
        "bounds": [[0.3, 0.9]] * 2,
        "gradient": "autograd",
        "best_params": list(params),
        "best_value": 0.01,
        "n_batches": 7,
        "seconds": {"online": online_s, "optimisation": online_s - 1, "posterior": 1.0, "landscape": 0.0},
        "geometry": {"distance": 0.0, "nearest": [2.0, 0.01]},
        "model_error_std": 0.1,
        "posterior": {
            "parameters": parameters,
            "correlation": [[1, -0.4], [-0.4, 1]],
            "sigma": [0.11] * 5,
            "sigma_source": "measured",
            "covariance": [[0.0025, 0], [0, 1]],
        },
        "roughness": {
            "radius": 0.002,
            "values": [0.011, 0.012, 0.009, 0.01],
            "optimum_value": 0.01,
            "spread": 0.003,
            "jacobian_step": 0.02,
            "jacobian_step_values": [0.02, 0.03, 0.01, 0.01],
        },
        "starts": [
            {
                "start": [0.55, 0.73],
                "params": list(params),
                "value": 0.01,
                "n_iterations": 3,
                "n_evaluations": 5,
                "message": "CONVERGENCE",
                "iterates": [{"params": [0.55, 0.73], "value": 0.2}],
            }
        ],
    }
    if runout is not None:
        data["runout"] = RUNOUT.to_config() if runout == "default" else runout
    path.write_text(json.dumps(data))
    return str(path)


def test_comparison_table_figures_and_report_section(tiny, tmp_path):
    runs = {}
    for label, (mu, e) in {"start": (0.55, 0.73), "gns": (0.5, 0.6), "quadratic": (0.8, 0.4)}.items():
        runs[label] = str(tmp_path / f"{label}.h5")
        write_trajectory(runs[label], simulate_collapse(tiny_case(mu, e, seed=0)))
    bench = tmp_path / "benchmarks"
    benchmarks = {
        "start": [_benchmark(bench / "start.tsv", 2.0)],
        "gns_dataset": [_benchmark(bench / f"dem_{k}.tsv", 3.0) for k in range(4)],
        "gns_training": [_benchmark(bench / "train.tsv", 100.0)],
        "gns_validation": [_benchmark(bench / "validate.tsv", 2.5)],
        "doe": [_benchmark(bench / f"doe_{k}.tsv", 1.0) for k in range(9)] + [str(bench / "missing.tsv")],
        "doe_validation": {"quadratic": [_benchmark(bench / "doe_validate.tsv", 1.5)]},
        "bayesopt": [_benchmark(bench / "bo.tsv", 30.0)],
    }
    bayesopt = _bayesopt_json(tmp_path / "bayesopt.json", RUNOUT.to_config())
    inverse = _inverse_json(tmp_path / "inverse.json", [0.5, 0.6])
    out = tmp_path / "out"
    routes = run_comparison(
        tiny["measured"],
        inverse,
        runs["gns"],
        runs["start"],
        out / "comparison.csv",
        out / "comparison.png",
        out / "runout.png",
        benchmarks,
        {"gns_dataset": 4, "doe": 9},
        runout=RUNOUT.to_config(),
        bayesopt_path=str(bayesopt),
        bayesopt_best_path=runs["gns"],
        doe_validation={"quadratic": runs["quadratic"]},
    )
    by_method = {(r.method, r.stage): r for r in routes}
    offline = by_method[("GNS inverse design", "offline")]
    online = by_method[("GNS inverse design", "online")]
    assert (offline.dem_runs, offline.wall_s) == (4, 112.0) and offline.validated_mse is None
    assert (online.dem_runs, online.wall_s) == (1, 15.0) and (online.friction, online.restitution) == (0.5, 0.6)
    doe = by_method[("DoE (quadratic)", "total")]
    assert (doe.dem_runs, doe.wall_s, doe.friction) == (10, 10.5, 0.8)
    assert by_method[("BO on DEM", "total")].dem_runs == 12
    start = by_method[("start point", "total")]
    assert start.validated_mse == pytest.approx(
        objective(read_trajectory(runs["start"]), _measured(tiny["measured"]), RUNOUT)
    )
    assert read_table(out / "comparison.csv") == routes
    for figure in ("comparison.png", "runout.png"):
        assert (out / figure).stat().st_size > 1000
    figures = {"tiny_target": {"comparison": out / "comparison.png", "runout": out / "runout.png"}}
    text = report_section(
        ["tiny_target"],
        [tiny["measured"]],
        [inverse],
        [out / "comparison.csv"],
        figures,
        tmp_path / "report" / "inverse.md",
    )
    assert "| GNS inverse design (online) | 1 |" in text and f"**{online.validated_mse:.3f}**" in text
    assert "restitution | 0.600 | 0.050 | [0.300, 0.900] | no: the measured runout hardly changes" in text
    assert "![validated objective against DEM runs and wall time (Table 5)](../out/comparison.png)" in text
    assert "| 0.550, 0.730 | 0.500, 0.600 | 0.2 -> 0.01 | 3 | 5 | CONVERGENCE |" in text
    assert "within 0.002 of the optimum it spans 0.003" in text
    # the section job: every column's figures lie beside its inverse.json, the BO's when it ran
    written = write_section(
        ["tiny_target"],
        [tiny["measured"]],
        [inverse],
        [out / "comparison.csv"],
        tmp_path / "report" / "inverse.md",
        bayesopt=True,
    )
    assert (tmp_path / "report" / "inverse.md").read_text() == written
    assert "![validated objective against DEM runs and wall time (Table 5)](../comparison.png)" in written
    assert "![Bayesian optimisation on DEM runs](../bayesopt.png)" in written


def _measured(path):
    from calibration.measured import load_column

    return load_column(path)


def test_comparison_refuses_results_scored_with_another_runout_method(tiny, tmp_path):
    """inverse.json and bayesopt.json must state the configured runout method: numbers read two
    ways are never put in one table (checked before any trajectory is read)."""

    def compare(inverse, bayesopt=None):
        out = tmp_path / "out"
        return run_comparison(
            tiny["measured"],
            inverse,
            tmp_path / "none.h5",
            tmp_path / "none.h5",
            out / "comparison.csv",
            out / "comparison.png",
            out / "runout.png",
            {},
            {"gns_dataset": 4, "doe": 9},
            runout=RUNOUT.to_config(),
            bayesopt_path=bayesopt,
        )

    other = RunoutMethod("connected_front").to_config()
    with pytest.raises(RunoutError, match=r"inverse design .*inverse_other\.json.*scored with runout"):
        compare(_inverse_json(tmp_path / "inverse_other.json", [0.5, 0.6], runout=other))
    with pytest.raises(RunoutError, match=r"inverse_none\.json: states no runout method"):
        compare(_inverse_json(tmp_path / "inverse_none.json", [0.5, 0.6], runout=None))
    bayesopt = _bayesopt_json(tmp_path / "bayesopt.json", dict(RUNOUT.to_config(), neighbour_radius=3.0))
    with pytest.raises(RunoutError, match=r"Bayesian optimisation .*bayesopt\.json.*scored with runout"):
        compare(_inverse_json(tmp_path / "inverse.json", [0.5, 0.6]), str(bayesopt))
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_route_rows_without_doe_or_bo_and_missing_times_stay_honest(tiny, tmp_path):
    trajectory = read_trajectory(tiny["paths"][0])
    inverse = json.loads(open(_inverse_json(tmp_path / "inverse.json", [0.3, 0.3])).read())
    routes = comparison_routes(
        _measured(tiny["measured"]),
        inverse,
        trajectory,
        trajectory,
        {"gns_dataset": (0.0, 2), "gns_training": 0.0, "gns_validation": 0.0},
        RUNOUT,
    )
    assert [r.method for r in routes] == ["start point", "GNS inverse design", "GNS inverse design"]
    assert math.isnan(routes[0].wall_s)  # no benchmark for the start run: n/a, not zero
    write_table(routes, tmp_path / "table.csv")
    with open(tmp_path / "table.csv") as handle:
        assert next(csv.reader(handle))[:4] == ["method", "stage", "dem_runs", "wall_s"]


def test_recovery_targets_avoid_training_cases_and_summary_applies_the_criteria():
    trained = [{"friction": 0.5, "restitution": 0.5}, {"friction": 0.7, "restitution": 0.4}]
    targets = recovery_targets(trained, 5, seed=3, min_distance=0.05)
    assert targets.shape == (5, 2)
    assert np.all((targets >= 0.36) & (targets <= 0.84))
    assert (
        min(
            np.linalg.norm(np.array([[t["friction"], t["restitution"]] for t in trained]) - p, axis=1).min()
            for p in targets
        )
        >= 0.05
    )
    row = lambda err, inside: {"mu_error": err, "mu_within": err <= 0.03, "inside": inside}  # noqa: E731
    good = recovery_summary([row(0.01, [True, True])] * 4 + [row(0.02, [False, True])])
    assert good["passes"] and good["truth_inside_95"] == 4 and good["mu_within"] == 5
    bad = recovery_summary([row(0.01, [True, True])] * 4 + [row(0.05, [True, True])])
    assert not bad["passes"] and bad["mu_error_max"] == 0.05
