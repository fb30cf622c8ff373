"""Bad input at the stages that read it: a truncated or NaN trajectory HDF5 at every reader, a
truncated training checkpoint, trajectories too short for the GNS window, a DEM run that fails
inside the Bayesian optimisation or the diagnosis, a DoE responses file with a missing run, a measured
CSV too short for the diagnosis, numbers in nested sections of the command line. Each gets a clear
error naming the file, key or line, or is recorded with its reason and left out, or is read as
meant; nothing computed is lost."""

from __future__ import annotations

import json
import logging
import shutil
import warnings
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pandas as pd
import pytest
import torch
import yaml
from snakemake.cli import parse_config
from snakemake.utils import update_config

import dem.engines
from calibration.bayesopt import BOSettings, bayesian_optimisation
from calibration.compare import bayesopt_on_dem, write_bayesopt
from calibration.dem_scoring import dem_evaluate, dem_runs
from calibration.design_runs import DEMRunner, Library, SimulationSettings, build_library
from calibration.diagnosis import DiagnosisSettings
from calibration.measured import load_column
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.observables import LibraryError, Observables
from calibration.optimise import OptimisationError, PointFailed, one_at_a_time
from calibration.residuals import MIN_RUNOUT_POINTS, DiagnosisError, NoiseModel, check_data, held_out_folds
from dem.case import CollapseCase
from dem.engines import EngineError
from dem.engines.builtin import OUTPUT, BuiltinEngine
from dem.grid import case_table
from dem.runout import RunoutMethod
from dem.trajectory import TrajectoryError, read_attrs, read_trajectory, write_trajectory
from doe.design import FACTORS, full_factorial
from doe.study import ResponsesError, collect_responses, fitted_runs, read_responses, run_analysis, write_responses
from gns.data import TrajectoryWindows
from gns.dataset import DatasetError, build_dataset, read_metadata
from gns.rollout import rollout_trajectory
from gns.settings import TrainSettings, simulator_config
from gns.simulator import LearnedSimulator
from gns.train import train
from pipeline.config import ConfigError, check_cross_keys, derive_columns, validate_config
from tests.gns_synthetic import sliding_grains, synthetic_dataset
from tests.test_gns_train import CONNECTED, TINY

RUNOUT = RunoutMethod()
NAN_FRAME, NAN_GRAIN = 5, 3
COLUMN = MeasuredColumn(  # 77 grains at size_scale 4: a DEM run takes a tenth of a second
    name="tiny",
    material="quartz",
    aspect_ratio=2.0,
    L_i=0.01,
    t_over_tstar=np.array([0.5, 1.0, 1.5, 2.0]),
    runout=np.array([0.2, 0.8, 1.5, 1.9]),
    runout_std=np.full(4, 0.05),
    source="test",
)


# -- a truncated or NaN trajectory at every reader -------------------------------------------------------
def bad_trajectory(folder: Path, kind: str) -> Path:
    """A trajectory file cut to the first half of its bytes ("truncated"), or whole with one NaN
    position at frame NAN_FRAME, grain NAN_GRAIN ("nan"; written past the writer, which refuses it)."""
    path = folder / f"{kind}.h5"
    write_trajectory(path, sliding_grains(0.4, 0.6, n_frames=24))
    if kind == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    else:
        with h5py.File(path, "r+") as f:
            f["positions"][NAN_FRAME, NAN_GRAIN, 1] = np.nan
    return path


def error_of(read, path: Path) -> str:
    """The message of the error read(path) raises."""
    with pytest.raises((TrajectoryError, EngineError, DatasetError)) as error:
        read(path)
    return str(error.value)


def recorded_doe_failure(path: Path) -> str:
    """The DoE reads each run's trajectory; a bad one is recorded as a failed run with its reason."""
    responses = collect_responses(pd.DataFrame({"run_id": ["run_0"]}), {"run_0": path}, COLUMN, RUNOUT)
    assert np.isnan(responses["mse"].iloc[0])
    return responses["failure"].iloc[0]


def read_engine_output(path: Path) -> None:
    """The builtin engine reads its own output file back."""
    shutil.copy(path, path.parent / OUTPUT)
    case = CollapseCase("quartz", L_i=0.01, aspect_ratio=2.0, friction=0.4, restitution=0.6, size_scale=4)
    BuiltinEngine().read(case, None, path.parent)


def read_gns_windows(path: Path) -> None:
    """The GNS training data: every window of C + 1 = 7 frames, read as training reads them."""
    windows = TrajectoryWindows([path], 6, ["friction", "restitution"])
    windows.batch(range(len(windows)))


def build_gns_dataset(path: Path) -> None:
    build_dataset({"train": [str(path)]}, path.parent / "metadata.json", "bad")


READERS = {  # each gives the message it raised or recorded
    "read_trajectory": lambda path: error_of(read_trajectory, path),
    "read_attrs": lambda path: error_of(read_attrs, path),
    "dem engine output": lambda path: error_of(read_engine_output, path),
    "gns dataset": lambda path: error_of(build_gns_dataset, path),
    "gns training windows": lambda path: error_of(read_gns_windows, path),
    "doe responses": recorded_doe_failure,
}
CASES = [
    (reader, kind) for reader in READERS for kind in ("truncated", "nan") if (reader, kind) != ("read_attrs", "nan")
]


@pytest.mark.parametrize(("reader", "kind"), CASES)
def test_a_truncated_or_nan_trajectory_is_named_by_every_reader(reader, kind, tmp_path):
    path = bad_trajectory(tmp_path, kind)
    message = READERS[reader](path)
    assert str(path) in message or str(path.parent / OUTPUT) in message, message
    if kind == "truncated":
        assert "truncated" in message
    else:
        assert f"dataset 'positions' is not finite at frame {NAN_FRAME}, grain {NAN_GRAIN}" in message


# -- a truncated checkpoint -------------------------------------------------------------------------------
@pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py
def test_a_truncated_checkpoint_is_refused_and_training_starts_clean(tmp_path, caplog):
    dataset = synthetic_dataset(tmp_path / "data", n_train=2, n_frames=12)
    settings = dict(TINY, steps=5, validate_every=5)
    clean = train(dataset, tmp_path / "clean", settings, runout=CONNECTED)
    out = tmp_path / "cut"
    out.mkdir()
    data = (tmp_path / "clean" / "checkpoint_last.pt").read_bytes()
    (out / "checkpoint_last.pt").write_bytes(data[: len(data) // 2])
    with caplog.at_level(logging.WARNING, logger="gns.train"):
        again = train(dataset, out, settings, runout=CONNECTED)  # resume, no restart_on_mismatch
    said = caplog.text
    assert f"{out / 'checkpoint_last.pt'}: not a readable training checkpoint, truncated?" in said
    assert "training starts clean from step 0" in said
    assert again["resumed_from"] is None and again["step"] == 5
    assert again["last_train_loss"] == clean["last_train_loss"]  # trained afresh, the same seed
    assert (out / "checkpoint_last.unreadable.pt").read_bytes() == data[: len(data) // 2]  # kept, not deleted
    assert torch.load(out / "checkpoint_last.pt", weights_only=False)["step"] == 5


# -- trajectories too short for the GNS window ----------------------------------------------------------
@pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py
def test_trajectories_shorter_than_the_gns_window_are_named_with_the_numbers(tmp_path):
    dataset = synthetic_dataset(tmp_path, n_train=2, n_frames=6)  # C = 6 input frames + 1 target: 7
    first = read_metadata(dataset)["splits"]["train"][0]
    with pytest.raises(DatasetError, match=rf"{first}: 6 frames, too few for one GNS window of 7 frames"):
        train(dataset, tmp_path / "gns", dict(TINY, steps=5), runout=CONNECTED)
    simulator = LearnedSimulator(simulator_config(read_metadata(dataset), TrainSettings.from_config(TINY)))
    short = read_trajectory(first)
    with pytest.raises(ValueError, match=rf"{first}: 6 frames, too few for a GNS rollout from C = 6"):
        rollout_trajectory(simulator, short)


# -- a DEM run that fails inside the Bayesian optimisation -------------------------------------------------
def test_bayesian_optimisation_records_a_failed_point_and_goes_on_without_it():
    def objective(p):
        if p[0] > 0.8:  # one point of the initial design
            raise PointFailed("EngineError: builtin engine failed on deck x.json: blew up at step 12")
        return float(np.sum((p - [0.42, 0.71]) ** 2))

    calls = []
    result = bayesian_optimisation(
        one_at_a_time(objective),
        [(0.3, 0.9), (0.3, 0.9)],
        ["friction", "restitution"],
        BOSettings(8, 4, seed=1),
        progress=lambda b, s, v: calls.append((b, v[0])),
    )
    history = result.history
    assert len(history.failed) >= 1 and history.n_calls == result.n_batches == 8 == len(calls)
    assert all(f["params"][0] > 0.8 and "blew up at step 12" in f["reason"] for f in history.failed)
    assert len(history.values) == 8 - len(history.failed) and all(np.isfinite(history.values))
    assert [b for b, _ in calls] == list(range(1, 9)) and sum(np.isnan(v) for _, v in calls) == len(history.failed)
    assert history.to_dict()["failed"] == history.failed and result.value == min(history.values)
    with pytest.raises(OptimisationError, match=r"no point .* evaluated \(3 failed\).*blew up"):
        bayesian_optimisation(
            one_at_a_time(lambda p: objective([0.9, 0.9])), [(0.3, 0.9)] * 2, ["mu", "e"], BOSettings(3, 2)
        )


def test_a_dem_run_that_fails_inside_bo_on_dem_is_recorded_and_never_averaged_in(tmp_path, monkeypatch):
    real = dem.engines.simulate_case
    seen = []

    def second_run_blows_up(case, config=None, packing=None, progress=None):
        seen.append((case.friction, case.restitution))
        if len(seen) == 2:
            raise EngineError("builtin engine failed on deck /tmp/x/case.json: blew up at step 345")
        return real(case, config, packing, progress)

    monkeypatch.setattr(dem.engines, "simulate_case", second_run_blows_up)
    fields = dict(size_scale=4, output_interval=0.004, duration_over_tstar=3.0, seed=0)
    history, best, _ = bayesopt_on_dem(COLUMN, fields, [(0.3, 0.9)] * 2, RUNOUT, budget=4, n_initial=3, seed=0)
    assert len(seen) == 4 and len(history.values) == 3
    assert history.failed == [
        {
            "params": pytest.approx(list(seen[1])),
            "reason": "EngineError: builtin engine failed on deck /tmp/x/case.json: blew up at step 345",
            "seconds": pytest.approx(history.failed[0]["seconds"]),
            "start": 0,
            "iteration": 0,
        }
    ]
    assert [best.attrs["friction"], best.attrs["restitution"]] == pytest.approx(history.best[0].tolist())
    write_bayesopt(history, 1.0, tmp_path / "bayesopt.json", RUNOUT)
    written = json.loads((tmp_path / "bayesopt.json").read_text())
    assert written["dem_runs"] == 4 and len(written["values"]) == 3 and "blew up at step 345" in str(written["failed"])

    monkeypatch.setattr(dem.engines, "simulate_case", lambda *a, **k: (_ for _ in ()).throw(EngineError("no solver")))
    with pytest.raises(OptimisationError, match=r"\(2 failed\).*EngineError: no solver"):
        bayesopt_on_dem(COLUMN, fields, [(0.3, 0.9)] * 2, RUNOUT, budget=2, n_initial=2)


# -- a DEM run that fails inside the diagnosis ------------------------------------------------------------
def test_a_dem_run_that_fails_in_the_diagnosis_is_recorded_and_left_out_of_the_means(monkeypatch):
    import calibration.design_runs

    settings = SimulationSettings(size_scale=4.0, packing_seeds=(101, 102))
    observables = Observables([COLUMN])
    runner = DEMRunner(observables, settings)
    folds = held_out_folds(observables)[:1]
    theta, fold_theta = np.array([0.5, 0.6]), np.array([0.55, 0.65])
    score = SimpleNamespace(theta=theta, fold_theta=[fold_theta])
    real = calibration.design_runs.simulate_case

    def blows_up_at_the_fit_on_packing_102(case, config=None, packing=None, progress=None):
        if case.seed == 102 and np.isclose(case.friction, 0.5):
            raise EngineError("builtin engine failed on deck /tmp/d/case.json: blew up at step 77")
        return real(case, config, packing=packing, progress=progress)

    monkeypatch.setattr(calibration.design_runs, "simulate_case", blows_up_at_the_fit_on_packing_102)
    runs = dem_runs(runner, Model(), score, folds, n_packings=2)
    assert runs.packings == [0] and runs.fit.shape == (1, 4) and len(runs.curves) == 1
    assert runs.fold_packings == [[0, 1]] and runs.folds[0].shape == (2, 4)
    assert runs.failed == [
        {
            "held_out": "",
            "parameters": {"friction": 0.5, "restitution": 0.6},
            "packing": 1,
            "reason": "EngineError: builtin engine failed on deck /tmp/d/case.json: blew up at step 77",
        }
    ]
    noise = NoiseModel(np.full(4, 0.05), np.full(4, 0.02), "test")
    score = dem_evaluate(runs, observables, folds, noise)
    one_run = np.sqrt(0.05**2 + 0.02**2 * 2)  # the std of a mean of the one run that ran
    assert score.chi2 == pytest.approx(float(np.sum(((runs.fit[0] - COLUMN.runout) / one_run) ** 2)))
    assert score.packings == [0] and len(score.objective_per_packing) == 1
    assert score.to_dict()["failed_runs"] == runs.failed

    monkeypatch.setattr(
        calibration.design_runs, "simulate_case", lambda *a, **k: (_ for _ in ()).throw(EngineError("no"))
    )
    with pytest.raises(DiagnosisError, match=r"base: every DEM run at its calibrated parameters failed.*packing 0: "):
        dem_runs(runner, Model(), SimpleNamespace(theta=theta, fold_theta=[fold_theta]), folds, n_packings=2)


def test_a_design_run_that_fails_is_recorded_in_the_library_and_left_out(tmp_path, monkeypatch):
    import calibration.design_runs

    real, calls = calibration.design_runs.simulate_case, []

    def second_run_blows_up(case, config=None, packing=None, progress=None):
        calls.append(case.seed)
        if len(calls) == 2:
            raise EngineError("builtin engine failed on deck /tmp/l/case.json: blew up at step 9")
        return real(case, config, packing=packing, progress=progress)

    monkeypatch.setattr(calibration.design_runs, "simulate_case", second_run_blows_up)
    observables = Observables([COLUMN])
    settings = SimulationSettings(size_scale=4.0, packing_seeds=(101, 102))
    library = build_library(observables, [Model()], settings, n_base=3)
    assert len(calls) == 5 and len(library.runs["base"].theta) == 4  # 3 design runs + 2 replicates, one failed
    assert library.runs["base"].stage.tolist() == ["design", "design", "replicate", "replicate"]
    assert [(f["model"], f["packing"], f["reason"]) for f in library.failed] == [
        ("base", 1, "EngineError: builtin engine failed on deck /tmp/l/case.json: blew up at step 9")
    ]
    library.save(tmp_path / "library.npz")
    assert Library.load(tmp_path / "library.npz").failed == library.failed  # kept with the runs

    monkeypatch.setattr(
        calibration.design_runs, "simulate_case", lambda *a, **k: (_ for _ in ()).throw(EngineError("x"))
    )
    with pytest.raises(LibraryError, match=r"every design run of base failed: .*EngineError: x"):
        build_library(observables, [Model()], settings, n_base=3)


# -- a DoE responses file with a missing run --------------------------------------------------------------
def test_a_doe_run_without_a_response_is_recorded_or_named_by_file_line_and_run(tmp_path):
    from test_objective import front_trajectory

    connected = RunoutMethod("connected_front")
    t_frames = np.arange(0, 4.01, 0.25)
    base = np.interp(t_frames, COLUMN.t_over_tstar, COLUMN.runout, left=0.0, right=COLUMN.runout[-1])
    design = full_factorial(n_levels=3)
    paths = {}
    for r in design.itertuples():
        front = COLUMN.L_i * (1 + (1 + 0.8 * (0.6 - r.friction) + 0.3 * (r.restitution - 0.5)) * base)
        traj = front_trajectory(front, L_i=COLUMN.L_i, aspect_ratio=COLUMN.aspect_ratio)
        traj.attrs.update(friction=r.friction, restitution=r.restitution)
        paths[r.run_id] = tmp_path / f"{r.run_id}.h5"
        write_trajectory(paths[r.run_id], traj)
    cut = paths["run_2"].read_bytes()
    paths["run_2"].write_bytes(cut[: len(cut) // 2])  # a run whose file was cut: recorded, left out

    responses = collect_responses(design, paths, COLUMN, connected)
    failed = responses[responses["failure"] != ""]
    assert failed["run_id"].tolist() == ["run_2"] and np.isnan(failed["mse"]).all()
    assert str(paths["run_2"]) in failed["failure"].iloc[0] and "truncated" in failed["failure"].iloc[0]
    fits, summary = run_analysis(responses, FACTORS, ["quadratic"])
    n = len(design)  # 3 x 3 and a replicated centre
    assert summary["n_runs"] == n and summary["n_fitted"] == n - 1 and list(summary["failed"]) == ["run_2"]
    assert summary["failures"].startswith(f"1 of {n} DEM runs failed and are left out of the fit: run_2: Trajectory")
    assert len(fitted_runs(responses)) == n - 1 and fits["quadratic"].result.nobs == n - 1

    write_responses(tmp_path / "responses.csv", responses)
    back = read_responses(tmp_path / "responses.csv", connected)  # the recorded failure reads back
    assert back["failure"].tolist() == responses["failure"].tolist()
    table = pd.read_csv(tmp_path / "responses.csv")
    table.loc[table["run_id"] == "run_5", "mse"] = np.nan  # a run with no response and no reason
    table.to_csv(tmp_path / "missing.csv", index=False)
    with pytest.raises(ResponsesError, match=r"missing\.csv: 1 design run\(s\) .*line 7, run run_5 \(mse empty\)"):
        read_responses(tmp_path / "missing.csv", connected)
    with pytest.raises(ResponsesError, match=r"no trajectory file for design run\(s\) \['run_8'\]"):
        collect_responses(design, {k: v for k, v in paths.items() if k != "run_8"}, COLUMN, connected)


# -- a measured CSV too short for the diagnosis: refused before any job runs ---------------------------------
ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"


def readme_example() -> list[str]:
    """The lines of the user's CSV that README.md "Calibrate your own column or campaign" shows, header first."""
    section = (ROOT / "README.md").read_text().split("## Calibrate your own column or campaign")[1].split("\n## ")[0]
    return next(block for block in section.split("```")[1::2] if block.lstrip().startswith("column,")).split()


def as_run_sh_main(csv: Path, *settings: str) -> dict:
    """config/config.yaml with `--config measured='{mine: <csv>}' *settings` as Snakemake hands it to
    the workflow (parse_config, then merged into the configfile's), through every parse-time check of
    workflow/rules/common.smk; returns the checked config."""
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    command_line = parse_config([f"measured={{mine: {csv}}}", *settings])
    update_config(config, command_line)
    config = derive_columns(validate_config(config, SCHEMA), command_line["measured"])
    check_cross_keys(config, case_table(config))
    return config


@pytest.mark.parametrize(
    "n_rows, message",
    [
        (2, f"column 'mine' has 2 runout point\\(s\\); the diagnosis .*needs at least {MIN_RUNOUT_POINTS} per column"),
        (3, r"3 measured value\(s\) .*models of up to 3 parameters .*needs at least 6 \(parameters \+ 3\)"),
    ],
    ids=["the-readmes-former-two-rows", "three-rows"],
)
def test_a_measured_csv_too_short_for_the_diagnosis_is_refused_at_parse_time(tmp_path, monkeypatch, n_rows, message):
    """The README's example as it was (its first two rows) ran until the diagnosis refused it; the
    diagnosis' own counts (calibration.residuals.check_data) now refuse it before any job runs."""
    monkeypatch.chdir(ROOT)  # the config's measured CSVs are relative to the workflow's root
    csv = tmp_path / "mine.csv"
    csv.write_text("\n".join(readme_example()[: n_rows + 1]) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a GeometryWarning on the way is not what this test looks at
        with pytest.raises(ConfigError, match=f"config key measured.mine: {csv}: {message}"):
            as_run_sh_main(csv)
        # without the diagnosis (and the model it picks) the reader's two points are enough
        assert as_run_sh_main(csv, "diagnosis={enabled: false}", "calibration={model: base}")["measured"]["mine"]
    section = validate_config(yaml.safe_load((ROOT / "config" / "config.yaml").read_text()), SCHEMA)["diagnosis"]
    models = DiagnosisSettings.from_config({k: v for k, v in section.items() if k != "enabled"}).models()
    with pytest.raises(DiagnosisError, match="runout point|too few to compare models"):  # as the job refused it
        check_data(Observables([load_column(csv)]), None, models, None)


def test_the_readmes_example_csv_passes_every_parse_time_check(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    csv = tmp_path / "mine.csv"
    csv.write_text("\n".join(readme_example()) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a GeometryWarning on the way is not what this test looks at
        config = as_run_sh_main(csv)
    assert config["inverse"]["dataset"]["mine"] == "inverse_mine"


# -- numbers in nested sections of the command line ------------------------------------------------------
def test_nested_numbers_given_on_the_command_line_are_read_as_the_schema_expects():
    """Snakemake reads `--config dem='{threads: 2}'` with YAML's BaseLoader: every scalar inside is a
    string. Where the schema expects a number, integer, boolean or null the string is read as one."""
    config = yaml.safe_load((ROOT / "config" / "tiny_all.yaml").read_text())
    command_line = [
        "dem={threads: 2, figures: false}",
        "diagnosis={runout_noise: null, channel_width: 1e-2, rule: {min_delta_bic_vs_base: 12}}",
        "doe={friction: [0.2, 0.8]}",
        "gns={per_dataset: {tiny_column: {steps: 5, wall_clamp: true}}}",
        "report={title: 2024}",
        "export_vtk=true",
    ]
    update_config(config, parse_config(command_line))
    assert config["dem"]["threads"] == "2" and config["doe"]["friction"] == ["0.2", "0.8"]  # as it arrives
    checked = validate_config(config, SCHEMA)
    assert (checked["dem"]["threads"], checked["dem"]["figures"], checked["export_vtk"]) == (2, False, True)
    assert (checked["diagnosis"]["runout_noise"], checked["diagnosis"]["channel_width"]) == (None, 0.01)
    assert checked["diagnosis"]["rule"]["min_delta_bic_vs_base"] == 12 and checked["doe"]["friction"] == [0.2, 0.8]
    assert checked["gns"]["per_dataset"] == {"tiny_column": {"steps": 5, "wall_clamp": True}}
    assert checked["report"]["title"] == "2024"  # a string where the schema wants one stays a string
    assert checked["dem"]["engine"] == "builtin" and checked["dem"]["min_grains_across"] == 5  # the file's keys kept
    update_config(config, parse_config(["dem={threads: two}", "gns={steps: 2.5}"]))
    with pytest.raises(ConfigError) as info:
        validate_config(config, SCHEMA)
    assert "dem.threads: 'two' has the wrong type; expected integer" in str(info.value)
    assert "gns.steps: '2.5' has the wrong type; expected integer" in str(info.value)
