"""The runout contract (dem.runout.RunoutMethod): known fronts of every method on hand-built grains,
the running maximum, lengths in grain diameters, bad settings and sparse frames named, the config
section and its schema, and every stage refusing numbers read by another method.

Scenes are square lattices of touching grains (diameter D): a lattice grain has its centre-to-centre
neighbours at 1, 1.41, 2, 2.24, 2.83, ... D, none near the dense rule's 2.4 D, so each neighbour
count below is exact.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
import yaml

from calibration.design_runs import Library
from calibration.diagnosis import DiagnosisSettings
from calibration.measured_column import MeasuredColumn
from calibration.observables import LibraryError, Observables
from calibration.residuals import DiagnosisError
from calibration.synthetic import noisy_columns
from dem.case import CollapseCase
from dem.runout import (
    METHODS,
    RunoutError,
    RunoutMethod,
    check_same_method,
    dense_mask,
    deposit_mask,
    profile_at,
    runout_at,
    runout_curve,
)
from dem.trajectory import Trajectory, read_trajectory, write_trajectory
from doe.study import read_responses
from gns.runout import soft_front_position
from pipeline.config import ConfigError, validate_config
from pipeline.inverse_design import model_error_from_evaluation

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"
R = 1e-3  # grain radius (m)
D = 2 * R  # grain diameter (m)
ROWS = 6  # height of the dense block (grains)
PARKED_X = 0.5  # stray grains wait out of the way here, 10 D apart: nobody's neighbours


def scene(width, floor, n_total=None, stray=()):
    """[N, 2] centres: a block of `width` x ROWS touching grains against the wall, a single layer of
    `floor` touching grains on the floor ahead of it, then the `stray` x positions (one grain each
    on the floor), then parked grains up to n_total."""
    block = [(R + i * D, R + j * D) for i in range(width) for j in range(ROWS)]
    layer = [(R + i * D, R) for i in range(width, width + floor)]
    loners = [(x, R) for x in stray]
    points = block + layer + loners
    n_total = n_total or len(points)
    points += [(PARKED_X + 10 * D * k, R) for k in range(n_total - len(points))]
    return np.array(points, float)


def trajectory(frames, radius=R, L_i=3 * D):
    """A Trajectory of the frames [T, N, 2] (m), one frame per 0.1 t*."""
    frames = np.asarray(frames, float)
    n = frames.shape[1]
    attrs = {"L_i": L_i, "dt_frame": 0.01, "t_star": 0.1}
    return Trajectory(frames, np.broadcast_to(np.asarray(radius, float), (n,)).copy(), np.zeros(n, np.int32), attrs)


# -- known fronts --------------------------------------------------------------------------------------
def test_dense_front_is_the_farthest_grain_of_the_dense_body():
    """Block of 10 x 6 grains, a 10-grain single layer ahead of it on the floor, two grains rolling
    alone far ahead: the dense front is the block's leading edge (10 D), never the layer or the
    loners; the connected front is the mean leading edge of the layer's 8 leading grains."""
    positions = scene(10, 10, stray=(0.30, 0.30 + 5 * D))
    radius = np.full(len(positions), R)
    dense = dense_mask(positions, radius)
    block, layer, loners = dense[:60].reshape(10, ROWS), dense[60:70], dense[70:]
    assert not layer.any() and not loners.any()  # a single layer has at most 7 such neighbours
    assert block[9, 0] and block[9, 1:5].all() and not block[9, 5]  # the edge column, but its top corner
    assert RunoutMethod("dense_front").front_position(positions, radius) == pytest.approx(10 * D)
    # the connected deposit holds block and layer, not the loners: mean x + r of floor grains 13..20
    assert deposit_mask(positions, radius)[:70].all() and not deposit_mask(positions, radius)[70:].any()
    assert RunoutMethod("connected_front").front_position(positions, radius) == pytest.approx(16.5 * D)
    assert RunoutMethod("connected_front", n_leading=4).front_position(positions, radius) == pytest.approx(18.5 * D)
    # the reached variants read one frame the same way
    assert RunoutMethod("dense_front_reached").front_position(positions, radius) == pytest.approx(10 * D)


def test_dense_mask_counts_as_every_pair_distance_does():
    """On scattered grains (a dense clump, a sparse spray) the mask is the brute-force count of the
    other centres within neighbour_radius mean diameters, for several thresholds."""
    rng = np.random.default_rng(3)
    positions = np.vstack([rng.uniform(0, 6 * D, (150, 2)), rng.uniform(0, 40 * D, (60, 2))])
    radius = rng.uniform(0.8, 1.2, len(positions)) * R
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
    for n_neighbours, neighbour_radius in ((8, 2.4), (3, 1.5), (20, 3.0)):
        reach = neighbour_radius * 2.0 * radius.mean()
        count = (distance <= reach).sum(axis=1) - 1
        expected = count >= n_neighbours
        assert 0 < expected.sum() < len(positions)
        assert dense_mask(positions, radius, n_neighbours, neighbour_radius).tolist() == expected.tolist()
    assert not dense_mask(positions[:1], radius[:1], 1).any()  # a lone grain has no neighbour


def test_dense_rule_counts_other_centres_within_the_radius_centre_to_centre():
    """A grain ringed by k grains at distance rho (in D): dense iff k >= n_neighbours (itself not
    counted) and rho <= neighbour_radius (centre to centre, not gap)."""

    def ring(k, rho):
        angles = 2 * np.pi * np.arange(k) / k
        centre = np.array([[0.05, 0.02]])
        return np.vstack([centre, centre + rho * D * np.column_stack([np.cos(angles), np.sin(angles)])])

    method = RunoutMethod("dense_front")
    positions = ring(8, 2.3)
    radius = np.full(len(positions), R)
    assert dense_mask(positions, radius).tolist() == [True] + [False] * 8
    assert method.front_position(positions, radius) == pytest.approx(0.05 + R)
    for k, rho in ((7, 2.3), (8, 2.5)):  # one neighbour short (the grain itself does not count); too far
        with pytest.raises(RunoutError, match="where it was"):
            method.front_position(ring(k, rho), np.full(k + 1, R), where="where it was")
    assert RunoutMethod("dense_front", neighbour_radius=2.6).front_position(ring(8, 2.5), radius) == pytest.approx(
        0.05 + R
    )
    assert RunoutMethod("dense_front", n_neighbours=7).front_position(ring(7, 2.3), radius[:8]) == pytest.approx(
        0.05 + R
    )


def test_reached_curves_are_the_running_maximum_and_never_decrease():
    """Frames in which the dense block and the floor layer grow, then shrink back (frame 3), then
    grow again: the instantaneous fronts move back, the "_reached" ones hold the farthest front."""
    widths, floors = [4, 6, 9, 7, 8, 10], [8, 8, 8, 2, 8, 8]
    n = 10 * ROWS + 8
    traj = trajectory([scene(w, f, n_total=n) for w, f in zip(widths, floors)])
    L_i = 3 * D
    t, dense = runout_curve(traj, "dense_front")
    assert dense == pytest.approx((np.array(widths) * D - L_i) / L_i)  # the block's edge, w D
    _, connected = runout_curve(traj, "connected_front")
    # 8 leading floor grains end at (w + f - 3.5) D on average; frame 3 (2 floor grains): 59 / 8 D
    expected = np.array([8.5, 10.5, 13.5, 59 / 8, 12.5, 14.5]) * D
    assert connected == pytest.approx((expected - L_i) / L_i)
    for front, instantaneous in (("dense_front", dense), ("connected_front", connected)):
        assert np.any(np.diff(instantaneous) < 0)  # it does move back
        t_reached, reached = runout_curve(traj, front + "_reached")
        assert np.array_equal(t_reached, t) and np.all(np.diff(reached) >= 0)
        assert reached == pytest.approx(np.maximum.accumulate(instantaneous))
    _, reached = RunoutMethod("dense_front_reached").curve(traj)
    assert reached == pytest.approx((np.array([4, 6, 9, 9, 9, 10]) * D - L_i) / L_i)
    # runout_at interpolates the chosen curve between frames (t/t* = 0.1 per frame)
    assert runout_at(traj, [0.35], "dense_front_reached") == pytest.approx((9 * D - L_i) / L_i)
    assert runout_at(traj, [0.35], "dense_front") == pytest.approx((7.5 * D - L_i) / L_i)


@pytest.mark.parametrize("method", METHODS)
def test_lengths_are_in_grain_diameters(method):
    """The same jittered, polydisperse collapse scaled x2 (positions, radii and L_i) has the same L*:
    gap_tolerance and neighbour_radius are counted in mean diameters, not metres."""
    rng = np.random.default_rng(3)
    n = 10 * ROWS + 12
    frames = [
        scene(w, f, n_total=n, stray=(0.1,)) + rng.normal(0, 0.05 * D, (n, 2))
        for w, f in [(6, 4), (8, 6), (10, 2), (9, 11)]
    ]
    radius = R * rng.uniform(0.9, 1.1, n)
    small = trajectory(frames, radius)
    large = trajectory(2 * np.array(frames), 2 * radius, L_i=2 * small.attrs["L_i"])
    t, runout = runout_curve(small, method)
    t2, runout2 = runout_curve(large, method)
    assert np.array_equal(t, t2) and runout2 == pytest.approx(runout, rel=1e-9, abs=1e-12)
    assert np.ptp(runout) > 0.5  # fronts that move were compared


def test_method_names_and_labels():
    assert METHODS == ("connected_front", "dense_front", "connected_front_reached", "dense_front_reached")
    method = RunoutMethod("connected_front_reached", n_leading=5)
    assert method.front_rule == "connected_front" and method.reached
    assert "5 leading grains" in method.label and "farthest reached" in method.label
    assert not RunoutMethod("dense_front").reached and "instantaneous" in RunoutMethod("dense_front").label
    assert RunoutMethod.from_config(method.to_config()) == method
    assert RunoutMethod.from_config("dense_front") == RunoutMethod(method="dense_front")
    assert RunoutMethod.from_config(None) == RunoutMethod() and RunoutMethod.from_config(method) is method


# -- bad settings and frames without a front ---------------------------------------------------------------
@pytest.mark.parametrize(
    "changes, key",
    [
        (dict(method="nope"), "runout.method"),
        (dict(neighbour_radius=-1.0), "runout.neighbour_radius"),
        (dict(neighbour_radius=float("nan")), "runout.neighbour_radius"),
        (dict(n_neighbours=0), "runout.n_neighbours"),
        (dict(n_neighbours=2.5), "runout.n_neighbours"),
        (dict(n_leading=0), "runout.n_leading"),
        (dict(n_leading=True), "runout.n_leading"),
        (dict(gap_tolerance=0.0), "runout.gap_tolerance"),
    ],
)
def test_bad_runout_settings_name_the_key(changes, key):
    with pytest.raises(RunoutError, match=key.replace(".", r"\.")):
        RunoutMethod(**changes)
    with pytest.raises(RunoutError, match=key.replace(".", r"\.")):
        RunoutMethod.from_config(changes)


def test_unknown_runout_key_is_named():
    with pytest.raises(RunoutError, match=r"unknown key\(s\) \['neighbor_radius'\]"):
        RunoutMethod.from_config({"neighbor_radius": 2.4})


def load_config():
    return yaml.safe_load((ROOT / "config" / "config.yaml").read_text())


@pytest.mark.parametrize(
    "section, key",
    [
        ({"method": "nope"}, "runout.method"),
        ({"neighbour_radius": -1}, "runout.neighbour_radius"),
        ({"n_neighbours": 0}, "runout.n_neighbours"),
        ({"gap_tolerance": 0}, "runout.gap_tolerance"),
        ({"neighbor_radius": 2.4}, "runout.neighbor_radius"),
    ],
)
def test_config_runout_section_is_validated(section, key):
    config = load_config()
    config["runout"] = section
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        validate_config(config, SCHEMA)


def test_config_defaults_are_the_classes_defaults():
    """One source of truth: the schema's defaults of `runout` are RunoutMethod()'s, key for key."""
    schema = yaml.safe_load(SCHEMA.read_text())["properties"]["runout"]
    defaults = {key: spec["default"] for key, spec in schema["properties"].items()}
    assert defaults == RunoutMethod().to_config()
    assert schema["properties"]["method"]["enum"] == list(METHODS)
    config = load_config()
    config.pop("runout", None)
    filled = validate_config(config, SCHEMA)["runout"]
    assert RunoutMethod.from_config(filled) == RunoutMethod() and filled == RunoutMethod().to_config()
    config = load_config()
    config["runout"] = {"method": "connected_front_reached", "n_leading": 4}
    assert RunoutMethod.from_config(validate_config(config, SCHEMA)["runout"]) == RunoutMethod(
        "connected_front_reached", n_leading=4
    )


def _sparse_file(path, dense_frames=0, n_frames=3):
    """Grains 10 D apart (nobody has a neighbour) after `dense_frames` frames of a dense block."""
    n = 10 * ROWS
    sparse = np.column_stack([0.01 + 10 * D * np.arange(n), np.full(n, R)])
    frames = [scene(10, 0) if k < dense_frames else sparse for k in range(n_frames)]
    attrs = CollapseCase("quartz", 0.02, 1.0, 0.5, 0.65).physical_parameters()
    attrs.update(engine="test", engine_version="0", dt_frame=0.01, x_min=0.0, x_max=2.0, y_min=0.0, y_max=0.35)
    write_trajectory(path, Trajectory(np.array(frames, np.float32), np.full(n, R), np.zeros(n, np.int32), attrs))
    return read_trajectory(path)


@pytest.mark.parametrize("method", ["dense_front", "dense_front_reached"])
def test_a_frame_too_sparse_for_the_dense_rule_is_an_error_naming_file_and_frame(tmp_path, method):
    path = tmp_path / "sparse.h5"
    traj = _sparse_file(path)
    assert traj.source == str(path)
    with pytest.raises(RunoutError, match=re.escape(f"{path}, frame 0: no grain has 8 grain centres within 2.4")):
        runout_curve(traj, method)
    with pytest.raises(RunoutError, match=re.escape(f"{path}, frame 0")):
        runout_at(traj, [0.01], method)
    later = _sparse_file(tmp_path / "later.h5", dense_frames=2)
    with pytest.raises(RunoutError, match=r"later\.h5, frame 2:"):
        runout_curve(later, method)
    assert np.isfinite(runout_curve(traj, "connected_front")[1]).all()  # the connected front always has one
    # the differentiable twin refuses the same frame
    with pytest.raises(RunoutError, match="frame 7: no grain qualifies"):
        soft_front_position(
            torch.as_tensor(traj.positions[0], dtype=torch.float64),
            torch.as_tensor(traj.radius),
            RunoutMethod(method),
            where="frame 7",
        )


# -- numbers read by another method are refused ------------------------------------------------------------
def test_check_same_method():
    method = RunoutMethod()
    check_same_method(method.to_config(), method, "here")
    with pytest.raises(RunoutError, match="here: states no runout method"):
        check_same_method(None, method, "here")
    with pytest.raises(RunoutError, match="here: scored with runout .*connected_front"):
        check_same_method(RunoutMethod("connected_front").to_config(), method, "here")
    with pytest.raises(RunoutError, match="here: scored with runout"):
        check_same_method(dict(method.to_config(), n_neighbours=7), method, "here")


def _responses(path, methods):
    table = pd.DataFrame(
        {
            "run_id": [f"run_{k}" for k in range(len(methods))],
            "friction": 0.5,
            "mse": np.linspace(0.1, 0.2, len(methods)),
        }
    )
    if methods[0] is not None:
        table["runout_method"] = [json.dumps(RunoutMethod.from_config(m).to_config(), sort_keys=True) for m in methods]
    table.to_csv(path, index=False)
    return path


def test_doe_responses_read_by_another_method_are_refused(tmp_path):
    connected = RunoutMethod("connected_front")
    same = _responses(tmp_path / "same.csv", [connected, connected])
    assert read_responses(same, connected)["mse"].tolist() == pytest.approx([0.1, 0.2])
    with pytest.raises(RunoutError, match=r"DoE responses .*same\.csv: scored with runout"):
        read_responses(same, RunoutMethod())
    with pytest.raises(RunoutError, match=r"old\.csv: states no runout method"):
        read_responses(_responses(tmp_path / "old.csv", [None]), connected)
    with pytest.raises(RunoutError, match=r"mixed\.csv: scored with runout"):
        read_responses(_responses(tmp_path / "mixed.csv", [connected, "dense_front"]), connected)


def test_gns_evaluation_read_by_another_method_is_refused(tmp_path):
    method = RunoutMethod()
    summary = tmp_path / "summary.json"
    # two test cases: the GNS 0.3 and 0.4 ahead of the DEM at t/t* = 2, on time at 0
    curves = [
        {"case": "a", "t_over_tstar": [0.0, 2.0], "dem": [0.0, 5.0], "gns": [0.0, 5.3]},
        {"case": "b", "t_over_tstar": [0.0, 2.0], "dem": [0.0, 4.0], "gns": [0.0, 3.6]},
    ]
    summary.write_text(json.dumps({"runout": method.to_config(), "runout_mse": 0.04, "runout_curves": curves}))
    # the error per point, RMS over the cases (interpolated between frames), not one number for all
    assert model_error_from_evaluation(summary, method, [0.0, 1.0, 2.0]) == pytest.approx(
        [0.0, np.sqrt((0.15**2 + 0.2**2) / 2), np.sqrt((0.3**2 + 0.4**2) / 2)]
    )
    assert model_error_from_evaluation(None, method, [1.0]) is None
    with pytest.raises(RunoutError, match=r"GNS evaluation .*summary\.json: scored with runout"):
        model_error_from_evaluation(summary, RunoutMethod("dense_front"), [1.0])
    summary.write_text(json.dumps({"runout": method.to_config(), "runout_mse": 0.04}))
    with pytest.raises(ValueError, match=r"GNS evaluation .*summary\.json: .*no runout curves"):
        model_error_from_evaluation(summary, method, [1.0])
    # every test rollout failed: no error measured, none joins the noise (as a NaN runout MSE did)
    failed = {"runout": method.to_config(), "runout_mse": None, "n_cases": 2, "n_failed": 2, "runout_curves": []}
    summary.write_text(json.dumps(failed))
    assert model_error_from_evaluation(summary, method, [1.0]) is None
    summary.write_text(json.dumps({"runout_mse": 0.04}))
    with pytest.raises(RunoutError, match=r"summary\.json: states no runout method"):
        model_error_from_evaluation(summary, method, [1.0])


def _columns():
    t = np.array([0.5, 1.0, 1.5, 2.0])
    return [MeasuredColumn("q1", "quartz", 1.0, 0.02, t, np.sqrt(t), np.full(len(t), 0.05), source="memory")]


def test_run_library_read_by_another_method_is_refused():
    connected = Observables(_columns(), RunoutMethod("connected_front"))
    assert connected.signature()["runout"] == RunoutMethod("connected_front").to_config()
    library = Library(connected.signature(), {"size_scale": 4.0}, {})
    library.check(Observables(_columns(), "connected_front"), [])  # the same method, named: fine
    with pytest.raises(LibraryError, match="runout method.*connected_front.*asked for.*dense_front_reached"):
        library.check(Observables(_columns()), [])
    unrecorded = {k: v for k, v in connected.signature().items() if k != "runout"}
    with pytest.raises(LibraryError, match="not recorded"):
        Library(unrecorded, {"size_scale": 4.0}, {}).check(connected, [])


def test_a_column_is_scored_by_the_runout_method_it_states():
    """The same run scored for two columns that differ only in the reading they state: each by its own (the
    config's when it states none, with the config's other settings either way), so the lab's connected front
    and the model's dense front give different L*; the synthetic data state the reading they used, and a
    library of runs read one way is refused for a column read another."""
    frames = [scene(4, 6)] * 6  # a block 4 grains long with a single layer of 6 ahead: 0.5 t*
    run = replace(trajectory(frames), attrs={**trajectory(frames).attrs, "diameter": D})
    t = np.array([0.1, 0.3, 0.5])
    plain = MeasuredColumn("q", "quartz", 1.0, 3 * D, t, np.ones(3), source="memory")
    lab = replace(plain, runout_method="connected_front_reached")
    configured = {"method": "dense_front_reached", "n_leading": 4}
    model, read_as_lab = (Observables([c], configured).from_trajectories([run]) for c in (plain, lab))
    np.testing.assert_allclose(model, runout_at(run, t, configured))
    np.testing.assert_allclose(read_as_lab, runout_at(run, t, {**configured, "method": "connected_front_reached"}))
    assert np.all(read_as_lab - model > 0.5)  # the layer ahead counts for the connected front only
    # the data a measurement makes say how they were read; a column stating the config's method is read as one
    # that states none, so its library stays the same
    (made,), _ = noisy_columns(
        Observables([plain], "connected_front_reached"), [run], 0.05, 5e-4, np.random.default_rng(0)
    )
    assert made.runout_method == "connected_front_reached"
    same = replace(plain, runout_method="dense_front_reached")
    assert Observables([same], configured).signature() == Observables([plain], configured).signature()
    library = Library(Observables([plain], configured).signature(), {"size_scale": 4.0}, {})
    with pytest.raises(LibraryError, match="columns read otherwise.*'q': 'connected_front_reached'"):
        library.check(Observables([lab], configured), [])


def test_diagnosis_settings_take_the_config_runout_section():
    settings = DiagnosisSettings.from_config({"n_base": 6}, {"method": "connected_front_reached"})
    assert settings.runout == RunoutMethod("connected_front_reached") and settings.n_base == 6
    assert settings.to_dict()["runout"] == RunoutMethod("connected_front_reached").to_config()
    assert DiagnosisSettings.from_config({}).runout == RunoutMethod()
    with pytest.raises(DiagnosisError, match=r"unknown setting\(s\) \['n_bases'\]"):
        DiagnosisSettings.from_config({"n_bases": 6})


def test_runout_study_statistics_have_known_answers():
    """dem.runout_study on hand-made curves: scatter, flicker, the chaos floor and the GNS's scores."""
    from dem.runout_study import chaos_floor, method_statistics

    t = np.array([0.5, 2.0, 3.0])  # one frame per phase: free fall, spreading, stopping
    first, others = np.array([0.0, 1.0, 2.0]), np.array([[0.0, 1.0, 3.0], [0.0, 1.0, 1.0]])
    floor = chaos_floor(t, first, others, gns=np.array([0.0, 1.0, 2.0]) + 0.5)
    assert floor["rerun_mse"] == pytest.approx(1 / 3) and floor["rerun_mse_each"] == pytest.approx([1 / 3, 1 / 3])
    assert floor["ideal_mse"] == pytest.approx(1 / 3)  # variance 0, 0, 1 across the three runs
    assert floor["ideal_mse_by_phase"] == pytest.approx({"free_fall": 0.0, "spreading": 0.0, "stopping": 1.0})
    assert floor["final_runout_spread"] == pytest.approx(1.0)
    assert floor["gns_mse"] == pytest.approx(0.25) and floor["gns_mse_to_mean"] == pytest.approx(0.25)
    assert "gns_mse" not in chaos_floor(t, first, others)

    curves = np.array([[0.0, 2.0, 1.5], [0.0, 1.0, 3.0]])  # the first run's front moves back by 0.5
    stats = method_statistics(t, curves)
    assert stats["flicker"] == pytest.approx(0.5) and stats["packings"] == 2
    assert stats["scatter_by_phase"]["spreading"] == pytest.approx(np.std([2.0, 1.0], ddof=1))
    assert stats["final_mean"] == pytest.approx(2.25)
    assert method_statistics(t, np.maximum.accumulate(curves, axis=1))["flicker"] == 0.0


def test_profile_is_read_like_an_image_at_the_stated_time_and_bin_width():
    """Known answer: the highest point of grain in the strip of a bin centred on each x (a centre in
    it shows its top, a grain beside it its rim), in the frame nearest the stated t/t*; 0 where no
    grain reaches into the strip."""
    block = scene(width=3, floor=4)  # block tops at 12 R, a single layer on the floor to x = 14 R
    later = block.copy()
    later[:, 1] = np.maximum(later[:, 1] - 4 * R, R)  # frame 1: the block has sunk by 2 grains
    traj = trajectory([block, later])  # frames at t/t* = 0 and 0.1
    x = [3 * R, 9 * R, 13 * R, 30 * R]
    np.testing.assert_allclose(profile_at(traj, 0.0, x, bin_width=2 * R), [12 * R, 2 * R, 2 * R, 0.0])
    np.testing.assert_allclose(profile_at(traj, 0.1, x, bin_width=2 * R), [8 * R, 2 * R, 2 * R, 0.0])
    np.testing.assert_allclose(profile_at(traj, 0.04, x, bin_width=2 * R), [12 * R, 2 * R, 2 * R, 0.0])  # nearest
    # a bin wide enough to reach the block from x = 7 R sees its top; a narrow one does not
    assert profile_at(traj, 0.0, [7.5 * R], bin_width=2 * R)[0] == pytest.approx(2 * R)
    assert profile_at(traj, 0.0, [7.5 * R], bin_width=6 * R)[0] == pytest.approx(12 * R)
    # a strip narrower than a grain between two columns of grains sees their rims, not nothing
    rim = 11 * R + np.sqrt(R**2 - (0.5 * R) ** 2)  # the block's top grain at 5 R, 0.5 R from the strip
    assert profile_at(traj, 0.0, [6 * R], bin_width=R)[0] == pytest.approx(rim)
    with pytest.raises(RunoutError, match="t/t\\* = 0.3 lies outside the simulated window"):
        profile_at(traj, 0.3, x, bin_width=2 * R)
    with pytest.raises(RunoutError, match="bin width must be positive"):
        profile_at(traj, 0.0, x, bin_width=0.0)
