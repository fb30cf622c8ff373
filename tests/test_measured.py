"""Measured-data CSV reader: the shipped curves, the schema and every bad-input check."""

import numpy as np
import pytest

from calibration.measured import (
    MeasuredDataError,
    MeasuredDataWarning,
    expected_final_runout,
    load_column,
    read_measured,
)
from dem.case import CaseError

HEADER = "column,material,aspect_ratio,L_i,kind,x,value,std\n"
QUARTZ_RUNOUT = [0.3, 1.2, 2.7, 4.2, 5.2, 6.0, 6.0]
TIMES = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5]


def write(tmp_path, text, name="m.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def runout_rows(values=QUARTZ_RUNOUT, times=TIMES, name="q", a=6.0, L_i=0.02, std=""):
    return "".join(f"{name},quartz,{a},{L_i},runout,{t},{v},{std}\n" for t, v in zip(times, values))


def test_shipped_curves_match_the_paper():
    quartz = load_column("data/measured/quartz_a6.csv")
    copper = load_column("data/measured/copper_a5.csv")
    assert (quartz.material, quartz.aspect_ratio, quartz.L_i) == ("quartz", 6.0, 0.02)
    np.testing.assert_allclose(quartz.t_over_tstar, TIMES)
    np.testing.assert_allclose(quartz.runout, QUARTZ_RUNOUT)
    assert (copper.material, copper.aspect_ratio) == ("copper", 5.0)
    np.testing.assert_allclose(copper.runout, [0.3, 1.0, 2.4, 3.6, 4.7, 5.2, 5.2])
    assert quartz.runout_std is None and quartz.profile_x is None
    assert quartz.H_i == pytest.approx(0.12)


def test_several_columns_noise_and_profile(tmp_path):
    text = (
        HEADER
        + runout_rows(name="a", std="0.1")
        + runout_rows(name="b", a=2.0, values=np.array(QUARTZ_RUNOUT) / 3)
        + "a,quartz,6.0,0.02,profile,0.0,0.03,\na,quartz,6.0,0.02,profile,0.05,0.01,\n"
    )
    path = write(tmp_path, "# a comment line\n" + text)
    columns = read_measured(path)
    assert list(columns) == ["a", "b"]
    np.testing.assert_allclose(columns["a"].runout_std, 0.1)
    np.testing.assert_allclose(columns["a"].profile_height, [0.03, 0.01])
    assert columns["b"].aspect_ratio == 2.0 and columns["b"].profile_x is None
    assert load_column(path, "b").name == "b"
    with pytest.raises(MeasuredDataError, match="say which one"):
        load_column(path)
    with pytest.raises(MeasuredDataError, match="no measured column 'c'"):
        load_column(path, "c")


def test_collapse_case_of_a_measured_column():
    quartz = load_column("data/measured/quartz_a6.csv")
    case = quartz.collapse_case(0.4, 0.5, size_scale=4.0, seed=2)
    assert (case.L_i, case.aspect_ratio, case.material.name) == (0.02, 6.0, "quartz")
    assert (case.friction, case.restitution, case.size_scale, case.seed) == (0.4, 0.5, 4.0, 2)
    with pytest.raises(CaseError, match="duration_over_tstar"):
        quartz.collapse_case(0.4, 0.5, size_scale=4.0, duration_over_tstar=3.0)


@pytest.mark.parametrize(
    "text, where",
    [
        (
            "column,material,aspect_ratio,kind,x,value\nq,quartz,6,runout,1,1\n",
            r"line 1: header lacks column\(s\) \['L_i'\]",
        ),
        (HEADER.replace(",std", ",stdev") + runout_rows(), r"line 1: unknown column\(s\) \['stdev'\]"),
        (HEADER + runout_rows().replace("2.7", "2,7"), "line 4: 9 fields"),
        (HEADER + runout_rows().replace(",2.7,", ",abc,"), "line 4, column 'value': 'abc' is not a number"),
        (HEADER + runout_rows().replace(",1.5,", ",nan,"), "line 4, column 'x': 'nan' is not finite"),
        (HEADER + runout_rows().replace("runout,2.0", "runout,1.0"), "line 5, column 'x'.*does not increase"),
        (HEADER + runout_rows().replace("runout,3.0", "runoff,3.0"), "line 7, column 'kind'"),
        (HEADER + runout_rows().replace("quartz", "sand"), "line 2, column 'material': unknown material 'sand'"),
        (HEADER + runout_rows(L_i=20), "line 2, column 'L_i'.*mm"),
        (
            HEADER + runout_rows()[:-1] + "\nq,quartz,5.0,0.02,runout,4.0,6.0,\n",
            "line 9, column 'aspect_ratio'.*differs",
        ),
        (HEADER + runout_rows(values=[0.3], times=[1.0]), "has 1 t/t\\* point"),
        (HEADER + runout_rows(std="0"), "line 2, column 'std'.*exact measurement"),
        (
            HEADER + runout_rows(std="0.1").replace("runout,2.0,4.2,0.1", "runout,2.0,4.2,"),
            "line 5, column 'std'.*every runout row",
        ),
        (HEADER, "no data rows"),
        ("# only a comment\n", "empty file"),
    ],
)
def test_bad_files_name_file_line_and_column(tmp_path, text, where):
    path = write(tmp_path, text)
    with pytest.raises(MeasuredDataError, match=where) as info:
        read_measured(path)
    assert str(path) in str(info.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(MeasuredDataError, match="no such measured-data file"):
        read_measured(tmp_path / "absent.csv")


def test_runout_in_metres_is_caught(tmp_path):
    # L - L_i in metres for the quartz column: L* x L_i, all values below 0.13
    metres = np.array(QUARTZ_RUNOUT) * 0.02
    path = write(tmp_path, HEADER + runout_rows(values=metres))
    with pytest.raises(MeasuredDataError, match="look like metres") as info:
        read_measured(path)
    assert "line 2, column 'value'" in str(info.value)
    # L itself in metres (L_i + runout) is caught too
    path = write(tmp_path, HEADER + runout_rows(values=metres + 0.02))
    with pytest.raises(MeasuredDataError, match="look like metres"):
        read_measured(path)


def test_small_genuine_runouts_pass(tmp_path):
    # a squat column (a = 0.3) genuinely runs out to L* ~ 0.4; early-time curves are never judged
    squat = write(tmp_path, HEADER + runout_rows(values=[0.05, 0.15, 0.25, 0.32, 0.36, 0.37, 0.37], a=0.3))
    assert read_measured(squat)["q"].runout.max() == pytest.approx(0.37)
    early = write(tmp_path, HEADER + runout_rows(values=[0.01, 0.05, 0.1], times=[0.2, 0.4, 0.6]), "early.csv")
    assert len(read_measured(early)["q"].runout) == 3


def test_implausible_runout_warns(tmp_path):
    assert expected_final_runout(6.0) == pytest.approx(6.27, abs=0.01)
    path = write(tmp_path, HEADER + runout_rows(values=np.array(QUARTZ_RUNOUT) * 10))
    with pytest.warns(MeasuredDataWarning, match="far from"):
        read_measured(path)
