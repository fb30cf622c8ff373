"""GNS training, resume after a kill, streaming windows, evaluation outputs, the stage's jobs
(pipeline.gns) and report section."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from dem.runout import RunoutMethod
from dem.trajectory import read_trajectory
from gns.data import TrajectoryWindows
from gns.dataset import DatasetError, read_metadata
from gns.evaluate import evaluate_rollouts, rollout_runout_mse, runout_error_at
from gns.settings import TrainSettings
from gns.simulator import CheckpointError, load_simulator
from gns.train import Trainer, train
from pipeline import gns as gns_stage
from pipeline.gns_section import section as gns_section
from tests.gns_synthetic import synthetic_dataset
from tests.same_bits import run_in_fresh_processes, sha256_state_dict

ROOT = Path(__file__).resolve().parents[1]
TINY = dict(
    latent_size=16,
    n_message_passing=2,
    connectivity_radius=4.0,
    noise_std=0.01,
    batch_size=2,
    log_every=5,
    checkpoint_every=5,
    validate_every=30,
    learning_rate=3e-3,
    learning_rate_decay_steps=1000,
)
# Twelve grains that never touch: no grain has 8 neighbours, so only the connected front reads them.
CONNECTED = RunoutMethod("connected_front")


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("gns_train"), n_train=4, n_frames=24)


@pytest.fixture(scope="module")
def trained(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("gns_run")
    result = train(dataset, out, dict(TINY, steps=60), runout=CONNECTED)
    return out, result


def test_training_lowers_the_loss_and_writes_its_outputs(trained, dataset):
    out, result = trained
    assert result["step"] == 60 and result["best"]["step"] in (30, 60)
    rows = list(np.genfromtxt(out / "metrics.csv", delimiter=",", names=True))
    assert [int(r["step"]) for r in rows] == list(range(5, 61, 5))
    assert np.mean([r["train_loss"] for r in rows[-3:]]) < 0.7 * np.mean([r["train_loss"] for r in rows[:2]])
    assert all(r["particles_per_graph"] == 12 and r["edges_per_node"] > 0 for r in rows)
    validated = [r for r in rows if np.isfinite(r["valid_one_step_loss"])]
    assert [int(r["step"]) for r in validated] == [30, 60]
    best = min(validated, key=lambda r: r["valid_runout_mse"])  # a failed rollout scores inf
    assert np.isfinite(best["valid_runout_mse"]) and result["best"]["step"] == int(best["step"])
    assert (out / "loss_curve.png").stat().st_size > 10_000
    model = torch.load(out / "model_best.pt", weights_only=False)
    assert model["valid_runout_mse"] == pytest.approx(result["best"]["valid_runout_mse"])
    load_simulator(out / "model_best.pt", read_metadata(dataset))


# a training in a fresh interpreter: the sha256 of its saved model's weights
TRAIN_IN_A_PROCESS = (
    "import json, sys, torch; from gns.train import train; from tests.same_bits import sha256_state_dict; "
    "train(sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), runout='connected_front'); "
    "print(sha256_state_dict(torch.load(sys.argv[2] + '/model_best.pt', weights_only=False)['state_dict']))"
)


def test_training_twice_in_fresh_processes_gives_the_same_weights_bit_for_bit(trained, dataset, tmp_path):
    """Reproducible training: the same settings and data give the same weights, bit for bit, in this process (one
    torch thread) and in two fresh interpreters with other hash seeds and thread counts (1 and 2;
    before gns.network.LayerNorm the thread count changed the LayerNorm gradients, so every weight)."""
    out, _ = trained
    here = sha256_state_dict(torch.load(out / "model_best.pt", weights_only=False)["state_dict"])
    settings = json.dumps(dict(TINY, steps=60))
    hashes = run_in_fresh_processes(
        TRAIN_IN_A_PROCESS,
        [[dataset, tmp_path / f"run_{k}", settings] for k in range(2)],
        hash_seeds=(1, 2),
        env=[{"OMP_NUM_THREADS": "1"}, {"OMP_NUM_THREADS": "2"}],
    )
    assert hashes == [here] * 2


def test_training_resumes_after_a_kill_exactly_as_if_uninterrupted(trained, dataset, tmp_path):
    settings = dict(TINY, steps=30)
    reference = train(dataset, tmp_path / "reference", settings, runout=CONNECTED)
    # the schedule does not depend on `steps`: a 30-step run repeats the 60-step run's first 30 steps
    # and validation bit for bit (calibration.gns_learning_rate_decay_steps stops the model's GNS early)
    longer = np.genfromtxt(trained[0] / "metrics.csv", delimiter=",", names=True)
    shorter = np.genfromtxt(tmp_path / "reference" / "metrics.csv", delimiter=",", names=True)
    assert len(shorter) == 6 and all(
        np.array_equal(shorter[k], longer[:6][k], equal_nan=True) for k in shorter.dtype.names if k != "steps_per_s"
    )

    killed = tmp_path / "killed"
    script = (
        "import json, sys, torch; torch.set_num_threads(1); from gns.train import train; "
        "train(sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), runout='connected_front')"
    )
    process = subprocess.Popen(
        [sys.executable, "-c", script, dataset, str(killed), json.dumps(dict(settings, steps=100_000))],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stderr=subprocess.PIPE,
    )
    deadline = time.time() + 60
    while not (killed / "checkpoint_last.pt").exists():
        assert process.poll() is None, process.stderr.read().decode()
        assert time.time() < deadline, "no checkpoint within 60 s"
        time.sleep(0.005)
    process.send_signal(signal.SIGKILL)
    process.wait()
    stopped_at = torch.load(killed / "checkpoint_last.pt", weights_only=False)["step"]
    assert 5 <= stopped_at < 30

    resumed = train(dataset, killed, settings, runout=CONNECTED)
    assert resumed["resumed_from"] == stopped_at and resumed["step"] == reference["step"] == 30
    assert resumed["last_train_loss"] == reference["last_train_loss"]
    assert resumed["best"] == reference["best"]
    a = torch.load(tmp_path / "reference" / "checkpoint_last.pt", weights_only=False)
    b = torch.load(killed / "checkpoint_last.pt", weights_only=False)
    assert all(torch.equal(a["model"]["state_dict"][k], b["model"]["state_dict"][k]) for k in a["model"]["state_dict"])
    assert [r["train_loss"] for r in a["history"]] == [r["train_loss"] for r in b["history"]]

    with pytest.raises(CheckpointError, match="other settings.*latent_size"):
        train(dataset, killed, dict(settings, latent_size=32), runout=CONNECTED)
    # the validation's runout method picks the saved model: another one is another training
    with pytest.raises(CheckpointError, match="other settings.*runout"):
        train(dataset, killed, settings, runout=RunoutMethod("connected_front_reached"))


def test_a_finished_training_rerun_writes_its_outputs_again_without_training(dataset, tmp_path):
    """Snakemake removes a job's outputs before it reruns it (e.g. --forcerun, or a param that only
    the model choice reads); the finished checkpoint must give back the same best model, not a
    missing file and not the last weights."""
    out = tmp_path / "run"
    first = train(dataset, out, dict(TINY, steps=60, validate_every=30), runout=CONNECTED)
    best_bytes = torch.load(out / "model_best.pt", weights_only=False)
    for name in ("model_best.pt", "metrics.csv", "loss_curve.png"):
        (out / name).unlink()
    again = train(dataset, out, dict(TINY, steps=60, validate_every=30), runout=CONNECTED)
    assert again["resumed_from"] == 60 and again["best"] == first["best"]
    restored = torch.load(out / "model_best.pt", weights_only=False)
    assert restored["step"] == first["best"]["step"]
    assert all(torch.equal(restored["state_dict"][k], best_bytes["state_dict"][k]) for k in best_bytes["state_dict"])
    assert (out / "metrics.csv").exists() and (out / "loss_curve.png").exists()
    # a checkpoint from before the kept best model: refused, and the restart really trains afresh
    payload = torch.load(out / "checkpoint_last.pt", weights_only=False)
    payload["best_model"] = None
    torch.save(payload, out / "checkpoint_last.pt")
    with pytest.raises(CheckpointError, match="no copy of the best model"):
        train(dataset, out, dict(TINY, steps=60, validate_every=30), runout=CONNECTED)
    # the workflow's job restarts on a mismatch (pipeline.gns.train)
    fresh = gns_stage.train(dataset, out, dict(TINY, steps=60, validate_every=30), CONNECTED)
    assert fresh["resumed_from"] is None and fresh["best"] == first["best"]  # retrained, same seed
    again = torch.load(out / "model_best.pt", weights_only=False)
    assert all(torch.equal(again["state_dict"][k], best_bytes["state_dict"][k]) for k in best_bytes["state_dict"])
    # the kept copy is a copy: the EMA updates the model's weights in place after the best step
    trainer = Trainer(dataset, tmp_path / "copy", TrainSettings.from_config(dict(TINY, steps=60)), runout=CONNECTED)
    trainer.save_best()
    kept = {k: v.clone() for k, v in trainer.best_payload["state_dict"].items()}
    with torch.no_grad():
        for parameter in trainer.averaged.parameters():
            parameter.add_(1.0)
    assert all(torch.equal(trainer.best_payload["state_dict"][k], kept[k]) for k in kept)


def test_dataset_without_statistics_is_refused(dataset, tmp_path):
    metadata = json.loads(Path(dataset).read_text())
    del metadata["velocity_std"]
    (tmp_path / "metadata.json").write_text(json.dumps(metadata))
    with pytest.raises(DatasetError, match="no normalisation statistics"):
        read_metadata(tmp_path / "metadata.json")


def test_windows_are_read_as_slices_of_the_files(dataset):
    metadata = read_metadata(dataset)
    paths = metadata["splits"]["train"]
    windows = TrajectoryWindows(paths, 6, ["friction", "restitution"], metadata["dt_frame"])
    assert len(windows) == 4 * (24 - 6)
    positions, entry = windows.window(18 + 7)  # second file, frames 7..13
    with h5py.File(paths[1]) as f:
        assert np.array_equal(positions, f["positions"][7:14])
    batch = windows.batch([0, 25])
    assert batch.position_sequence.shape == (24, 6, 2) and batch.context.graph_index.tolist() == [0] * 12 + [1] * 12
    assert torch.equal(batch.next_position[12:], torch.from_numpy(positions[-1]))


def test_evaluation_rolls_out_test_cases_and_scores_them(trained, dataset, tmp_path):
    out, _ = trained
    metadata = read_metadata(dataset)
    dem_path = metadata["splits"]["test"][0]
    gns = gns_stage.rollout(out / "model_best.pt", dem_path, tmp_path / "rollout.h5", dataset)
    written = read_trajectory(tmp_path / "rollout.h5")
    assert written.attrs["engine"] == "gns" and written.n_frames == 24
    assert np.array_equal(written.positions[:6], read_trajectory(dem_path).positions[:6])
    assert gns.attrs["rollout_valid"] == 1
    summary = evaluate_rollouts([(dem_path, tmp_path / "rollout.h5")], tmp_path / "eval", CONNECTED)
    assert summary["n_cases"] == 1 and np.isfinite(summary["runout_mse"]) and summary["position_mse_d2"] > 0
    assert (tmp_path / "eval" / "runout_curves.png").exists()
    assert (tmp_path / "eval" / "snapshots" / f"{Path(dem_path).stem}.png").exists()
    dem = read_trajectory(dem_path)
    assert rollout_runout_mse(dem, dem, CONNECTED) == 0.0
    # the evaluation scores the curves it drew; read afresh from the files they give the same MSE
    assert summary["runout_mse"] == pytest.approx(rollout_runout_mse(dem, written, CONNECTED), rel=1e-12)
    assert summary["runout"] == CONNECTED.to_config()  # the summary states how it read L*
    # its curves give the error per t/t* point: at the frames, the MSE over frames again
    t_frames = summary["runout_curves"][0]["t_over_tstar"]
    assert np.mean(runout_error_at(summary, t_frames) ** 2) == pytest.approx(summary["runout_mse"], rel=1e-9)
    assert json.loads((tmp_path / "eval" / "summary.json").read_text())["runout"] == CONNECTED.to_config()
    # the stage's jobs: the same scores from the path lists, and the report section linking its figures
    gns_stage.evaluate([dem_path], [tmp_path / "rollout.h5"], tmp_path / "stage", CONNECTED)
    assert (tmp_path / "stage" / "summary.json").read_text() == (tmp_path / "eval" / "summary.json").read_text()
    fragment = tmp_path / "report" / "gns.md"
    text = gns_section(
        ["synthetic"], [tmp_path / "stage" / "summary.json"], [out / "loss_curve.png"], [out / "metrics.csv"], fragment
    )
    assert fragment.read_text() == text
    assert "| synthetic | 60 |" in text and "### synthetic" in text and "connected" in text
    links = re.findall(r"\]\(([^)]+)\)", text)
    assert len(links) == 3 and all((fragment.parent / link).exists() for link in links)
