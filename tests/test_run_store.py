"""The store of a long job's finished DEM runs (dem/run_store.py): a run read back from it has the
bits of the run that was stored; a job killed midway and run again reuses the runs it had finished
and writes what an uninterrupted job writes; every job that runs many DEM collapses keeps its runs."""

from __future__ import annotations

import contextlib
import inspect
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import pipeline.calibrated
import pipeline.calibrated_contenders
import pipeline.calibrated_doe
import pipeline.diagnosis
import pipeline.inverse
import pipeline.inverse_design
from calibration.calibrated import model_record
from calibration.model import Model
from dem.case import CollapseCase
from dem.engines import FAILURES, simulate_case
from dem.packing import settle_column
from dem.run_store import active_store, kept_runs, runs_folder
from dem.runout import RunoutMethod
from dem.trajectory import Trajectory, TrajectoryError, read_trajectory
from pipeline.calibrated_column import CalibratedColumn

ROOT = Path(__file__).resolve().parents[1]
# 77 grains, 1 t*: a third of a second a run
CASE = CollapseCase(
    "quartz", L_i=0.01, aspect_ratio=2.0, friction=0.5, restitution=0.6, size_scale=4.0, seed=3,
    duration_over_tstar=1.0, name="tiny",
)  # fmt: skip
TIMINGS = ("wall_time_s", "particle_steps_per_second")  # two runs of one case differ in these only


def assert_same_bits(a: Trajectory, b: Trajectory, but: tuple[str, ...] = ()) -> None:
    """Every array (dtype and bits) and every attribute (but those named) of a equal b's."""
    for name in ("positions", "radius", "particle_type"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name
    assert {k: v for k, v in a.attrs.items() if k not in but} == {k: v for k, v in b.attrs.items() if k not in but}


def test_a_run_read_from_the_store_has_the_stored_runs_bits_and_is_not_run_again(tmp_path):
    fresh = simulate_case(CASE)  # no store: today's run
    folder = tmp_path / "runs"
    with kept_runs(folder) as store:
        first = simulate_case(CASE)
        assert dict(store.ran) == {"collapse": 1, "packing": 1} and not store.reused
        stored = {path.name: path.stat().st_mtime_ns for path in store.stored()}
        assert sorted(name.split("-")[0] for name in stored) == ["collapse", "packing"]
        fractions = []
        second = simulate_case(CASE, progress=fractions.append)
        # read, not run: no run made, no file written again, the progress at its end at once
        assert dict(store.ran) == {"collapse": 1, "packing": 1} and dict(store.reused) == {"collapse": 1}
        assert {path.name: path.stat().st_mtime_ns for path in store.stored()} == stored and fractions == [1.0]
        assert not list(folder.glob("*.work"))  # the work folder goes once the run is stored
        # what determines the result is in the key: another seed, or a packing given, is another run
        other = simulate_case(CASE.replace(seed=4))
        packing = settle_column(CASE)  # the packing the first run settled, read back
        assert dict(store.reused) == {"collapse": 1, "packing": 1}
        from_packing = simulate_case(CASE, packing=packing)
        assert dict(store.ran) == {"collapse": 3, "packing": 2}
    assert active_store() is None and not folder.exists()  # the job done: the folder is removed
    assert_same_bits(first, second)  # every attribute, its wall time too: the same run
    assert_same_bits(first, fresh, but=TIMINGS)  # and the run a job outside any store makes
    assert_same_bits(from_packing, fresh, but=TIMINGS)
    assert not np.array_equal(other.positions, first.positions)


def test_a_failed_run_is_not_stored_and_fails_again_and_an_interrupted_block_keeps_its_runs(tmp_path):
    folder = tmp_path / "runs"
    packing = settle_column(CASE)
    short = Trajectory(packing.positions[:, :-1], packing.radius[:-1], packing.particle_type[:-1], packing.attrs)
    with pytest.raises(RuntimeError, match="stopped"), kept_runs(folder) as store:
        simulate_case(CASE)
        for _ in range(2):  # the same failure each time, as without a store
            with pytest.raises(FAILURES) as failed:
                simulate_case(CASE, packing=short)
            assert failed.type is TrajectoryError and f"packing has {CASE.n_particles - 1} grains" in str(failed.value)
        assert dict(store.ran) == {"collapse": 1, "packing": 1}
        assert len(store.stored()) == 2 and not list(folder.glob("*.work"))
        raise RuntimeError("stopped")
    assert len(list(folder.glob("*.h5"))) == 2  # an exception keeps the folder for the rerun
    with kept_runs(folder) as store:
        simulate_case(CASE)
        assert dict(store.reused) == {"collapse": 1} and not store.ran
    assert not folder.exists()


# -- a job killed midway -------------------------------------------------------------------------------
# what workflow/scripts/calibrated_doe.py runs, in a process of its own (doe_job's JSON as argument)
KILLABLE_DOE = (
    "import json, sys; from pipeline.calibrated_column import CalibratedColumn; "
    "from pipeline.calibrated_doe import run_model_doe; a = json.loads(sys.argv[1]); "
    "run_model_doe(CalibratedColumn.read(*a['column'], **a['kwargs']), *a['args'])"
)
DOE_TIMINGS = ("seconds", "dem_seconds", "analysis_time_s")


def doe_job(csv: Path, model_json: Path, out: Path) -> dict:
    """The calibrated_doe job of the base model's 3 x 3 CCD + 1 centre replicate (10 runs) into
    `out`, as JSON: CalibratedColumn.read's arguments ("column", "kwargs") and run_model_doe's rest."""
    outputs = [str(out / name) for name in ("doe.json", "doe_responses.csv", "doe_surface.png")]
    return {
        "column": [str(csv), str(model_json), {"size_scale": 4.0, "channel_width": 0.01}],
        "kwargs": {"runout": RunoutMethod().to_config(), "dem": None, "name": "tiny"},
        "args": [*outputs, {"doe_centre_replicates": 1}],
    }


def run_doe_job(job: dict) -> dict:
    """Run a doe_job as workflow/scripts/calibrated_doe.py does."""
    return pipeline.calibrated_doe.run_model_doe(CalibratedColumn.read(*job["column"], **job["kwargs"]), *job["args"])


def counts(**runs: int) -> str:
    """The store's log line's count of runs by kind, e.g. "3 collapse(s), 4 packing(s)"."""
    return ", ".join(f"{n} {kind}(s)" for kind, n in sorted(runs.items()) if n) or "none"


def doe_outputs(out: Path) -> tuple[dict, pd.DataFrame]:
    """doe.json and the responses table without the wall times (which no two attempts share)."""
    result = json.loads((out / "doe.json").read_text())
    for key in DOE_TIMINGS:
        result.pop(key)
    return result, pd.read_csv(out / "doe_responses.csv").drop(columns="dem_wall_time_s")


def test_a_killed_doe_job_rerun_reuses_its_finished_runs_and_writes_what_an_uninterrupted_one_does(tmp_path, caplog):
    csv = tmp_path / "tiny.csv"
    csv.write_text(
        "column,material,aspect_ratio,L_i,kind,x,value,std\n"
        + "".join(f"tiny,quartz,2,0.01,runout,{t},{v},\n" for t, v in ((0.5, 0.2), (1.0, 0.8), (1.5, 1.5), (2.0, 1.9)))
    )
    model_json = tmp_path / "model.json"
    model_json.write_text(json.dumps(model_record(Model(), "the config asks for the base model (mu, e)", "tiny")))
    reference = doe_job(csv, model_json, tmp_path / "reference")
    run_doe_job(reference)

    killed = tmp_path / "killed"
    runs = runs_folder(killed / "doe.json")
    process = subprocess.Popen(
        [sys.executable, "-c", KILLABLE_DOE, json.dumps(doe_job(csv, model_json, killed))],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.time() + 120
        while len(list(runs.glob("collapse-*.h5"))) < 3:
            assert process.poll() is None, process.stderr.read().decode()
            assert time.time() < deadline, "fewer than 3 runs stored within 120 s"
            time.sleep(0.005)
    finally:
        with contextlib.suppress(ProcessLookupError):
            process.send_signal(signal.SIGKILL)
        process.wait()
    collapses = list(runs.glob("collapse-*.h5"))
    packings = list(runs.glob("packing-*.h5"))
    assert 3 <= len(collapses) < 10 and not (killed / "doe.json").exists(), "the kill came too late"
    for path in collapses + packings:  # whatever lies under a run's name is whole (atomic writes)
        read_trajectory(path)

    caplog.clear()
    with caplog.at_level("INFO", logger="dem.run_store"):
        run_doe_job(doe_job(csv, model_json, killed))
    # the finished runs read back, not run again (nor their packings settled); the rest run, the one
    # in flight among them (from its packing, where that was stored)
    reused = counts(collapse=len(collapses), packing=len(packings) - len(collapses))
    ran = counts(collapse=10 - len(collapses), packing=10 - len(packings))
    assert f"DEM runs kept in {runs}: reused {reused}; ran {ran}; folder removed" in caplog.text
    assert not runs.exists()
    result, responses = doe_outputs(killed)
    expected, expected_responses = doe_outputs(tmp_path / "reference")
    assert result == expected
    pd.testing.assert_frame_equal(responses, expected_responses, check_exact=True)
    assert (killed / "doe_surface.png").read_bytes() == (tmp_path / "reference" / "doe_surface.png").read_bytes()


# -- every job that runs many DEM collapses keeps its runs ---------------------------------------------
# {workflow script (its rule): the stage function it calls}; pipeline/calibrated_inverse.py's job
# runs the GNS only (its optimum's DEM runs are calibrated_validate's)
LONG_DEM_JOBS = {
    "diagnosis_library": pipeline.diagnosis.run_library,
    "diagnosis": pipeline.diagnosis.run_diagnosis,
    "calibrated_doe": pipeline.calibrated_doe.run_model_doe,
    "calibrated_bayesopt": pipeline.calibrated.run_model_bayesopt,
    "inverse_bayesopt": pipeline.inverse.run_bayesopt,
    "calibrated_validate": pipeline.calibrated.run_validation,
    "calibrated_contenders": pipeline.calibrated_contenders.run_contenders,  # the contenders across a
    "calibrated": pipeline.calibrated.run_calibrated,  # the runoff, the finer-scale transfer, the predictions
    "inverse_recovery": pipeline.inverse_design.run_recovery,  # its targets' DEM runs, several packings each
}


@pytest.mark.parametrize("script", sorted(LONG_DEM_JOBS))
def test_every_long_dem_job_keeps_its_runs_beside_its_output(script):
    job = LONG_DEM_JOBS[script]
    text = (ROOT / "workflow/scripts" / f"{script}.py").read_text()
    assert f"import {job.__name__}\n" in text, f"workflow/scripts/{script}.py no longer calls {job.__name__}"
    beside = getattr(job, "keeps_runs_beside", None)
    assert beside in inspect.signature(job).parameters, f"{job.__name__} does not keep its DEM runs (keeps_runs)"


def test_a_batch_made_ahead_on_two_processes_gives_the_bits_of_the_runs_made_in_turn(tmp_path, caplog):
    """dem.run_ahead: a validation on three packings and predictions at two aspect ratios, their runs
    made ahead by two worker processes, give the numbers of the same calls made one run after the
    other, and the job's own calls read every run from the store (none made twice); the workers run
    niced."""
    from calibration.calibrated import validate
    from calibration.design_runs import SimulationSettings
    from calibration.measured_column import MeasuredColumn
    from calibration.prediction import predict
    from dem.run_ahead import WORKER_NICENESS, batch_workers, run_ahead

    column = MeasuredColumn(
        name="tiny", material="quartz", aspect_ratio=2.0, L_i=0.01, t_over_tstar=np.array([0.5, 1.0]),
        runout=np.array([0.2, 0.8]), source="test",
    )  # fmt: skip
    settings, runout, theta = SimulationSettings(size_scale=4.0), RunoutMethod(), (0.5, 0.6)
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("one core: no worker beside the job")
    assert batch_workers({"workers": 2}) == 2 and batch_workers({"workers": 2, "threads": 2}) == 1
    assert batch_workers({"workers": 10**3}) == len(os.sched_getaffinity(0)) and batch_workers(None) == 1
    outcomes = {}
    for workers in (1, 2):
        dem = {"engine": "builtin", "workers": workers}
        with kept_runs(tmp_path / f"runs{workers}") as store, caplog.at_level("INFO", logger="dem.run_ahead"):
            validation = validate("base", Model(), column, theta, settings, runout, dem, n_packings=3)
            prediction = predict(Model(), column, theta, settings, [1.0, 3.0], runout, dem)
            outcomes[workers] = (validation.curves, prediction.final_runout, prediction.final_height)
            made_here = dict(store.ran)
            if workers == 2:  # the workers yield to the scheduled jobs (nice), the job itself does not
                assert store.workers.submit(os.nice, 0).result() == min(19, os.nice(0) + WORKER_NICENESS)
        assert store.workers is None  # the job's worker processes end with its store
        assert made_here == ({"collapse": 5, "packing": 5} if workers == 1 else {})  # all 5 read from the store
    assert outcomes[1] == outcomes[2]  # floats compared exactly: the same bits
    assert "3 run(s) made ahead" in caplog.text and "2 run(s) made ahead" in caplog.text
    assert run_ahead([CASE, CASE.replace(seed=4)], {"workers": 2}) == 0  # outside a store: nothing
