"""Dataset metadata: splits, normalisation statistics from the training split only, checks."""

import json

import numpy as np
import pytest

from dem.case import CollapseCase
from dem.trajectory import GRAIN, Trajectory, engine_attrs, write_trajectory
from gns.dataset import DatasetError, build_dataset, load_dataset_metadata, plot_dataset


def write_motion(path, friction, L_i=0.01, speed=0.0, accel=0.0, n_frames=12, n=5, output_interval=0.002, rng=None):
    """A trajectory of n grains moving with constant velocity `speed` and acceleration `accel`
    (m per frame, m per frame^2) in x and -y, plus seeded noise, with a real case's attributes."""
    case = CollapseCase("quartz", L_i, 2.0, friction, 0.65, size_scale=4, output_interval=output_interval)
    rng = rng or np.random.default_rng(0)
    t = np.arange(n_frames)[:, None, None]
    start = rng.uniform(0.001, 0.009, (1, n, 2))
    direction = np.array([1.0, -0.5])
    positions = start + (speed * t + 0.5 * accel * t**2) * direction + rng.normal(0, 1e-5, (n_frames, n, 2))
    traj = Trajectory(
        positions.astype(np.float32),
        np.full(n, 0.5 * case.diameter),
        np.full(n, GRAIN, np.int32),
        engine_attrs(case, "synthetic", "test"),
    )
    write_trajectory(path, traj)
    return positions.astype(np.float32).astype(np.float64)


@pytest.fixture
def three_splits(tmp_path):
    rng = np.random.default_rng(1)
    train = [tmp_path / f"train_{k}.h5" for k in range(3)]
    arrays = [
        write_motion(p, friction=0.3 + 0.1 * k, speed=1e-4 * (k + 1), accel=2e-5, rng=rng) for k, p in enumerate(train)
    ]
    # valid/test move 100x faster: they must not touch the statistics, but do set the ranges
    write_motion(tmp_path / "valid.h5", friction=0.9, L_i=0.012, speed=1e-2, accel=1e-3, n=7, rng=rng)
    write_motion(tmp_path / "test.h5", friction=0.2, speed=1e-2, accel=1e-3, n_frames=15, rng=rng)
    splits = {
        "train": [str(p) for p in train],
        "valid": [str(tmp_path / "valid.h5")],
        "test": [str(tmp_path / "test.h5")],
    }
    return splits, arrays


def test_statistics_come_from_the_training_split_only(tmp_path, three_splits):
    splits, arrays = three_splits
    meta = build_dataset(splits, tmp_path / "meta" / "metadata.json", "synthetic")
    velocity = np.concatenate([(x[1:] - x[:-1]).reshape(-1, 2) for x in arrays])
    acceleration = np.concatenate([(x[2:] - 2 * x[1:-1] + x[:-2]).reshape(-1, 2) for x in arrays])
    np.testing.assert_allclose(meta["velocity_mean"], velocity.mean(axis=0), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(meta["velocity_std"], velocity.std(axis=0), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(meta["acceleration_mean"], acceleration.mean(axis=0), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(meta["acceleration_std"], acceleration.std(axis=0), rtol=1e-9, atol=1e-15)
    assert meta["velocity_mean"][0] > 0 > meta["velocity_mean"][1]  # the x / -y direction of motion
    assert meta["velocity_mean"][0] < 1e-3  # the fast valid/test grains were left out


def test_metadata_contents_and_round_trip(tmp_path, three_splits):
    splits, _ = three_splits
    out = tmp_path / "metadata.json"
    meta = build_dataset(splits, out, "synthetic")
    assert meta == load_dataset_metadata(out)
    assert meta["name"] == "synthetic" and meta["dim"] == 2 and meta["splits"] == splits
    assert meta["dt_frame"] == pytest.approx(0.002)
    assert meta["bounds"] == [[0.0, 0.5], [0.0, 0.35]]
    assert meta["n_particles"] == {"min": 5, "max": 7, "mean": pytest.approx(27 / 5)}
    assert meta["parameter_ranges"]["friction"] == pytest.approx([0.2, 0.9])
    assert meta["parameter_ranges"]["L_i"] == pytest.approx([0.01, 0.012])
    assert meta["parameter_ranges"]["H_i"] == pytest.approx([0.02, 0.024])
    assert meta["parameter_ranges"]["restitution"] == [0.65, 0.65]
    assert meta["material_diameter"] == pytest.approx(4 * 425e-6)
    assert meta["sequence_length"] == 12 and meta["sequence_length_max"] == 15
    assert meta["n_cases"] == {"train": 3, "valid": 1, "test": 1}
    assert [p.name for p in tmp_path.iterdir() if p.suffix == ".tmp"] == []


def test_mixed_frame_intervals_fail_naming_the_file(tmp_path, three_splits):
    splits, _ = three_splits
    odd = tmp_path / "odd.h5"
    write_motion(odd, friction=0.5, output_interval=0.003)
    splits["test"].append(str(odd))
    with pytest.raises(DatasetError, match=r"odd\.h5: dt_frame = 0\.003 s differs from 0\.002 s of .*train_0\.h5"):
        build_dataset(splits, tmp_path / "metadata.json", "synthetic")
    assert not (tmp_path / "metadata.json").exists()


def test_empty_train_split_is_an_error(tmp_path, three_splits):
    splits, _ = three_splits
    with pytest.raises(DatasetError, match="train split is empty"):
        build_dataset(dict(splits, train=[]), tmp_path / "metadata.json", "synthetic")


def test_load_names_the_file_and_the_missing_key(tmp_path, three_splits):
    splits, _ = three_splits
    good = build_dataset(splits, tmp_path / "metadata.json", "synthetic")
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps({k: v for k, v in good.items() if k not in ("velocity_std", "acceleration_mean")}))
    with pytest.raises(DatasetError, match=r"broken\.json: no normalisation statistics: .*'velocity_std'"):
        load_dataset_metadata(broken)
    broken.write_text(json.dumps({k: v for k, v in good.items() if k != "dt_frame"}))
    with pytest.raises(DatasetError, match=r"broken\.json: missing key\(s\) \['dt_frame'\]"):
        load_dataset_metadata(broken)
    broken.write_text(json.dumps(dict(good, velocity_std=[0.0, 1.0])))
    with pytest.raises(DatasetError, match="velocity_std.*zero component"):
        load_dataset_metadata(broken)
    with pytest.raises(DatasetError, match="nowhere.json: no such dataset metadata file"):
        load_dataset_metadata(tmp_path / "nowhere.json")


def test_summary_figure_reports_final_runout_per_case(tmp_path, three_splits):
    splits, arrays = three_splits
    meta = build_dataset(splits, tmp_path / "metadata.json", "synthetic")
    # five scattered grains: only the connected front has one (no grain has 8 neighbours)
    final = plot_dataset(meta, tmp_path / "summary.png", "connected_front")
    assert (tmp_path / "summary.png").stat().st_size > 10_000
    assert set(final) == {p for paths in splits.values() for p in paths}
    # the valid grains travel ~0.1 m in x: their runout must far exceed the slow training cases'
    assert final[splits["valid"][0]] > 5 * max(final[p] for p in splits["train"])


def test_dataset_stage_summary_table_and_report_section(tmp_path, monkeypatch):
    """pipeline.dataset: metadata, the case table CSV with each case's final L* (read from the
    trajectories where the DEM stage writes them), the report section with relative links."""
    from pipeline.dataset import build, summarise
    from pipeline.dataset_section import write_section

    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(2)
    rows, splits = [], {"train": [], "valid": [], "test": []}
    for k, split in enumerate(["train", "train", "valid", "test"]):
        path = f"results/dem/syn/trajectories/case_{k:03d}.h5"
        write_motion(tmp_path / path, friction=0.3 + 0.1 * k, speed=1e-3 * (k + 1), rng=rng)
        splits[split].append(path)
        rows.append({"dataset": "syn", "case_id": f"case_{k:03d}", "split": split, "friction": 0.3 + 0.1 * k})
    meta_path = "results/datasets/syn/metadata.json"
    meta = build(splits, meta_path, "syn")
    assert meta["n_cases"] == {"train": 2, "valid": 1, "test": 1}
    out = summarise(
        meta_path, "results/datasets/syn/summary.png", "results/datasets/syn/cases.csv", rows, "connected_front"
    )
    final = plot_dataset(meta, tmp_path / "again.png", "connected_front")
    assert [r["final_L_star"] for r in out] == [round(final[p], 4) for p in sum(splits.values(), [])]
    assert "final_L_star" not in rows[0]  # the caller's rows are left alone
    lines = (tmp_path / "results/datasets/syn/cases.csv").read_text().splitlines()
    assert lines[0] == "dataset,case_id,split,friction,final_L_star" and len(lines) == 5
    assert lines[1].endswith(f",{out[0]['final_L_star']}")
    text = write_section([meta_path], ["results/datasets/syn/summary.png"], "results/report/dataset.md")
    assert (tmp_path / "results/report/dataset.md").read_text() == text
    assert "| syn | 2/1/1 | 5-5 | 12-12 | 2 | 0.3-0.6 | 0.65 | 10 | 2 |" in text
    assert "](../datasets/syn/summary.png)" in text


def test_an_extended_models_dataset_takes_its_parameter_and_names_a_file_without_it(tmp_path, three_splits):
    """The GNS of an extended model takes its mechanism's parameter (a trajectory attribute) after
    (mu, e); a trajectory that does not record it is refused, by name."""
    splits, _ = three_splits
    meta = build_dataset(
        splits, tmp_path / "metadata.json", "extended", ("friction", "restitution", "rolling_friction")
    )
    assert list(meta["parameter_ranges"]) == [
        "friction",
        "restitution",
        "rolling_friction",
        "L_i",
        "H_i",
        "aspect_ratio",
    ]
    assert meta["parameter_ranges"]["rolling_friction"] == [0.0, 0.0]
    with pytest.raises(DatasetError, match=r"train_0\.h5: no attribute\(s\) \['bond_number'\]"):
        build_dataset(splits, tmp_path / "bond.json", "extended", ("friction", "restitution", "bond_number"))
    assert not (tmp_path / "bond.json").exists()


def test_the_base_models_runs_join_an_extended_models_dataset_at_its_off_values(tmp_path, three_splits):
    """One GNS for both models (calibration.gns_shared): the base model's runs, which do not record
    the mechanism's parameter, take its off value (a number, or the parameter it follows), in the
    ranges and in the windows the GNS trains on; the metadata records what it filled in."""
    from gns.data import TrajectoryWindows
    from gns.dataset import with_off_values

    splits, _ = three_splits
    names = ("friction", "restitution", "bond_number", "gate_slowness")
    off = {"bond_number": 0.0, "gate_slowness": "friction"}
    meta = build_dataset(splits, tmp_path / "shared.json", "shared", names, off)
    assert meta["parameter_off"] == off
    assert meta["parameter_ranges"]["bond_number"] == [0.0, 0.0]
    assert meta["parameter_ranges"]["gate_slowness"] == meta["parameter_ranges"]["friction"] == [0.2, 0.9]
    assert load_dataset_metadata(tmp_path / "shared.json")["parameter_off"] == off
    windows = TrajectoryWindows(splits["train"], 6, names, off=off)
    frictions = [0.3, 0.4, 0.5]
    assert np.allclose([f["parameters"] for f in windows.files], [[m, 0.65, 0.0, m] for m in frictions])
    # a value the run records is its own, not the off value
    assert with_off_values({"friction": 0.4, "bond_number": 3.0}, off) == {
        "friction": 0.4,
        "bond_number": 3.0,
        "gate_slowness": 0.4,
    }
    with pytest.raises(DatasetError, match=r"train_0\.h5: trajectory attributes lack \['bond_number'\]"):
        TrajectoryWindows(splits["train"], 6, names, off={"gate_slowness": 0.0})


def test_the_dataset_stage_joins_the_base_runs_with_the_models_off_values(tmp_path, three_splits):
    """pipeline.dataset.build: a calibrated model's dataset with the base model's runs of the column
    (base_splits) takes each mechanism's off value from the model (here the floor friction follows
    the grains'); the base runs join each split; without a model they are refused."""
    from calibration.calibrated import model_record
    from calibration.model import model_named
    from pipeline.dataset import build

    splits, _ = three_splits
    model = tmp_path / "model.json"
    model.write_text(json.dumps(model_record(model_named("basal_friction"), "test")))
    own = {"train": splits["train"][:2], "valid": [], "test": []}
    base = {"train": splits["train"][2:], "valid": splits["valid"], "test": splits["test"]}
    meta = build(own, tmp_path / "meta.json", "calibrated_x", model, base_splits=base)
    assert meta["parameter_off"] == {"friction_base": "friction"}
    assert meta["splits"]["train"] == splits["train"] and meta["splits"]["test"] == splits["test"]
    with pytest.raises(ValueError, match="dataset plain: the base model's runs join only a calibrated model's"):
        build(own, tmp_path / "plain.json", "plain", base_splits=base)
