"""The scale ladder (dem/scale_ladder.py, pipeline/scale_ladder.py): its runs are case-table rows, and
its summary holds what the runs' own files say.

A tiny ladder, size_scale 4 and 3 of an 8 mm quartz column (a = 1, some 20 and 35 grains), 2 packings each, 1 t*
of collapse, run through the DEM stage's own functions (pipeline.dem: deck, settle, run), then read
by the stage; every number of the summary is checked against the trajectories and packings read
directly. About 5 s, most of it the engine's first compile.
"""

import json

import numpy as np
import pytest

from dem.grid import case_from_row
from dem.runout import RunoutMethod, final_height
from dem.scale_ladder import READ_AT, case_id, case_rows
from dem.trajectory import read_attrs, read_trajectory
from pipeline.dem import run_case, settle, write_deck
from pipeline.scale_ladder import run_scale_ladder

SPEC = {
    "size_scales": [3, 4],
    "packings": 2,
    "seed": 7,
    "material": "quartz",
    "aspect_ratio": 1.0,
    "L_i": 0.008,
    "friction": 0.5,
    "restitution": 0.6,
    "duration_over_tstar": 1.0,
}
METHOD = "connected_front"  # not the default: the summary must read the method it is given


def test_case_rows_are_the_ladder_coarsest_first_each_packing_its_seed():
    rows = case_rows(dict(SPEC, size_scales=[1.5, 4]))
    ids = ["scale4_packing0", "scale4_packing1", "scale1p5_packing0", "scale1p5_packing1"]
    assert [row["case_id"] for row in rows] == ids
    assert [row["seed"] for row in rows] == [7, 8, 7, 8] and {row["dataset"] for row in rows} == {"scale_ladder"}
    case = case_from_row(rows[2])
    assert (case.size_scale, case.friction, case.duration_over_tstar, case.material.name) == (1.5, 0.5, 1.0, "quartz")
    assert case_id(1.5, 0) == "scale1p5_packing0"


@pytest.fixture(scope="module")
def ladder(tmp_path_factory):
    """The tiny ladder run as the DAG runs it, then read by the stage: (folder, rows, summary)."""
    folder = tmp_path_factory.mktemp("ladder")
    rows = case_rows(SPEC)
    for row in rows:
        stem = folder / row["case_id"]
        write_deck(row, f"{stem}.json")
        settle(f"{stem}.json", f"{stem}_packing.h5")
        run_case(f"{stem}.json", f"{stem}_packing.h5", f"{stem}.h5", "builtin", {}, False, folder / "work")
    summary = run_scale_ladder(
        [folder / f"{r['case_id']}.h5" for r in rows],
        [folder / f"{r['case_id']}_packing.h5" for r in rows],
        folder / "summary.json",
        folder / "ladder.png",
        folder / "report" / "scale_ladder.md",
        METHOD,
    )
    return folder, rows, summary


def test_summary_holds_what_the_runs_files_say(ladder):
    folder, rows, summary = ladder
    assert json.loads((folder / "summary.json").read_text()) == summary
    assert summary["runout"]["method"] == METHOD and summary["case"]["friction"] == 0.5
    by_scale = summary["by_size_scale"]
    assert list(by_scale) == ["4", "3"]  # coarsest first
    for label, entry in by_scale.items():
        ids = [r["case_id"] for r in rows if r["size_scale"] == float(label)]
        runs = [read_trajectory(folder / f"{i}.h5") for i in ids]
        packings = [read_attrs(folder / f"{i}_packing.h5") for i in ids]
        assert entry["seeds"] == [7, 8] and entry["n_particles"] == runs[0].n_particles
        assert entry["grains_across"] == pytest.approx(0.008 / (425e-6 * float(label)))
        # L* at t/t* = 1 by the method given, read off each run directly; 2, 3.5, 4 lie past the runs
        at_1 = [float(RunoutMethod.from_config(METHOD).at(run, [1.0])[0]) for run in runs]
        assert set(entry["runout_at"]) == {"1"} and READ_AT[0] == 1.0
        at = entry["runout_at"]["1"]
        assert at["per_packing"] == pytest.approx(at_1, abs=1e-12) and at["mean"] == pytest.approx(np.mean(at_1))
        assert at["std"] == pytest.approx(np.std(at_1, ddof=1)) and at["std"] > 0
        assert entry["final_t_over_tstar"] == pytest.approx(1.0)
        assert entry["final_runout"]["per_packing"] == pytest.approx(at_1, abs=1e-12)  # the last frame is t* 1
        heights = [final_height(r.positions[-1].astype(float), r.radius) / r.attrs["H_i"] for r in runs]
        assert entry["final_height_over_H_i"]["per_packing"] == pytest.approx(heights)
        assert entry["settle_s"]["per_packing"] == [p["wall_time_s"] for p in packings]
        assert entry["collapse_s"]["per_packing"] == [r.attrs["wall_time_s"] for r in runs]
        assert all(s > 0 for s in entry["settle_s"]["per_packing"] + entry["collapse_s"]["per_packing"])


def test_section_and_figure(ladder):
    folder, _, summary = ladder
    text = (folder / "report" / "scale_ladder.md").read_text()
    assert "](../ladder.png)" in text
    assert "connected front" in text and "From size_scale 4 to 3 the final L*" in text
    final = summary["by_size_scale"]["3"]["final_runout"]
    assert f"| 3 | {summary['by_size_scale']['3']['n_particles']:,} (" in text
    assert f"{final['mean']:.2f} +- {final['std']:.2f}" in text
    figure = folder / "ladder.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 10_000
