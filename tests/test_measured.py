"""Measured-data CSV reader: the shipped curves, the schema and every bad-input check."""

import codecs
import dataclasses
from dataclasses import replace

import numpy as np
import pytest

from calibration.measured import MeasuredDataError, MeasuredDataWarning, load_column, read_measured
from calibration.measured_column import MeasuredColumn
from calibration.scaling_laws import quasi_2d_runout
from calibration.synthetic import write_measured_csv
from dem.case import CaseError
from dem.runout import RunoutMethod

HEADER = "column,material,aspect_ratio,L_i,kind,x,value,std\n"
QUARTZ_RUNOUT = [0.3, 1.2, 2.7, 4.2, 5.2, 6.0, 6.0]
TIMES = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5]


def write(tmp_path, text, name="m.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def runout_rows(values=QUARTZ_RUNOUT, times=TIMES, name="q", a=6.0, L_i=0.02, std="", extra=""):
    return "".join(f"{name},quartz,{a},{L_i},runout,{t},{v},{std}{extra}\n" for t, v in zip(times, values))


READ_HEADER = "column,material,aspect_ratio,L_i,kind,x,value,std,read_at,bin_width\n"


def profile_rows(x=(0.01, 0.02, 0.03), height=(0.03, 0.01, 0.002), std="", read_at="", bin_width=""):
    """Profile rows of column q; std, read_at, bin_width: one value for every row or one per row."""
    cells = [v if isinstance(v, list) else [v] * len(x) for v in (std, read_at, bin_width)]
    return "".join(f"q,quartz,6.0,0.02,profile,{xi},{h},{s},{r},{b}\n" for xi, h, s, r, b in zip(x, height, *cells))


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
        # a spreadsheet's CSV in a locale whose decimal mark is ',', and a tab-separated file
        (
            HEADER.replace(",", ";") + runout_rows().replace(",", ";").replace(".", ","),
            r"line 1: the header's fields are separated by ';'; the schema's delimiter is ','",
        ),
        (
            "# a comment, with a comma\n" + HEADER.replace(",", "\t") + runout_rows().replace(",", "\t"),
            r"line 2: the header's fields are separated by a tab; the schema's delimiter is ','",
        ),
        ("# only a comment\n", "empty file"),
        # how a profile was read (read_at, bin_width) and its std
        (READ_HEADER + runout_rows(extra=",4.0,") + profile_rows(), "line 2, column 'read_at': a runout row"),
        (READ_HEADER + runout_rows(extra=",,") + profile_rows(read_at="0"), "line 9, column 'read_at'.*t/t\\* > 0"),
        (
            READ_HEADER + runout_rows(extra=",,") + profile_rows(bin_width="0.0002"),
            "line 9, column 'bin_width'.*below one grain",
        ),
        (
            READ_HEADER + runout_rows(extra=",,") + profile_rows(bin_width="-1"),
            "line 9, column 'bin_width'.*below one grain",
        ),
        (
            READ_HEADER + runout_rows(extra=",,") + profile_rows(read_at=["4", "", "4"]),
            "line 10, column 'read_at'.*every profile row or on none",
        ),
        (
            READ_HEADER + runout_rows(extra=",,") + profile_rows(read_at=["4", "4.5", "4"]),
            "line 10, column 'read_at'.*differs from 4 on line 9",
        ),
        (
            READ_HEADER + runout_rows(extra=",,") + profile_rows(std=["0.001", "", "0.001"]),
            "line 10, column 'std'.*every profile row or on none",
        ),
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


def test_runout_in_percent_is_caught(tmp_path):
    percent = np.array(QUARTZ_RUNOUT) * 100
    path = write(tmp_path, HEADER + runout_rows(values=percent))
    with pytest.raises(MeasuredDataError, match="look like percent") as info:
        read_measured(path)
    assert "line 2, column 'value'" in str(info.value) and "L* = (L - L_i)/L_i as a fraction" in str(info.value)
    # an early curve too: no front is ever 25x past the final runout of its column
    early = write(tmp_path, HEADER + runout_rows(values=percent[:3], times=TIMES[:3]), "early.csv")
    with pytest.raises(MeasuredDataError, match="look like percent"):
        read_measured(early)
    signed = write(tmp_path, HEADER + runout_rows(values=[f"{v:g}%" for v in percent]), "signed.csv")
    with pytest.raises(MeasuredDataError, match=r"line 2, column 'value': '30%' is a percentage; give L\*"):
        read_measured(signed)


@pytest.mark.parametrize("a", [0.3, 1.0, 2.8, 6.0, 20.0])
def test_long_genuine_runouts_are_never_read_as_percent(tmp_path, a):
    # 10x the scaling law's final runout: implausible (a warning), never refused as percent
    values = 10 * quasi_2d_runout(a) * np.linspace(0.1, 1.0, len(TIMES))
    with pytest.warns(MeasuredDataWarning, match="far from"):
        column = read_measured(write(tmp_path, HEADER + runout_rows(values=values, a=a)))["q"]
    np.testing.assert_allclose(column.runout, values)


def test_small_genuine_runouts_pass(tmp_path):
    # a squat column (a = 0.3) genuinely runs out to L* ~ 0.4; early-time curves are never judged
    squat = write(tmp_path, HEADER + runout_rows(values=[0.05, 0.15, 0.25, 0.32, 0.36, 0.37, 0.37], a=0.3))
    assert read_measured(squat)["q"].runout.max() == pytest.approx(0.37)
    early = write(tmp_path, HEADER + runout_rows(values=[0.01, 0.05, 0.1], times=[0.2, 0.4, 0.6]), "early.csv")
    assert len(read_measured(early)["q"].runout) == 3


def test_implausible_runout_warns(tmp_path):
    assert quasi_2d_runout(6.0) == pytest.approx(6.27, abs=0.01)
    path = write(tmp_path, HEADER + runout_rows(values=np.array(QUARTZ_RUNOUT) * 10))
    with pytest.warns(MeasuredDataWarning, match="far from"):
        read_measured(path)


# -- files as spreadsheets save them -----------------------------------------------------------------------
def same_columns(read, expected):
    """Two reads of one file's text hold the same columns, every field (but the file's name) equal."""
    assert list(read) == list(expected)
    for name, column in read.items():
        for field in dataclasses.fields(MeasuredColumn):
            if field.name != "source":
                np.testing.assert_equal(getattr(column, field.name), getattr(expected[name], field.name), field.name)


@pytest.mark.parametrize(
    "comment", ["", "# L* = (L - L_i)/L_i, t* = sqrt(H_i/g)\n"], ids=["header-first", "comment-first"]
)
def test_a_byte_order_mark_is_read_past(tmp_path, comment):
    """A spreadsheet's "CSV UTF-8" starts with a byte-order mark: the file reads as the same text without it."""
    text = (
        comment
        + HEADER
        + runout_rows(std="0.1")
        + "q,quartz,6.0,0.02,profile,0.0,0.03,\nq,quartz,6.0,0.02,profile,0.05,0.01,\n"
    )
    marked = tmp_path / "marked.csv"
    marked.write_bytes(codecs.BOM_UTF8 + text.encode("utf-8"))
    same_columns(read_measured(marked), read_measured(write(tmp_path, text)))


def test_a_file_in_another_encoding_names_the_line_and_asks_for_utf8(tmp_path):
    text = HEADER + runout_rows() + "# grains of 425 \u00b5m\n"
    path = tmp_path / "latin.csv"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(
        MeasuredDataError, match=r"line 9: byte 0xb5 .*is not UTF-8 .*'\u00b5'.*save it as UTF-8"
    ) as info:
        read_measured(path)
    assert str(path) in str(info.value)
    path.write_bytes(text.encode("utf-8"))  # the same text in UTF-8 reads
    assert len(read_measured(path)["q"].runout) == len(TIMES)


def test_profile_reading_and_std_are_kept_and_defaults_said(tmp_path):
    """A profile states when and how it was read and its noise; an old file gets defaults, said."""
    stated = read_measured(
        write(
            tmp_path, READ_HEADER + runout_rows(extra=",,") + profile_rows(std="0.0005", read_at="4", bin_width="0.001")
        )
    )["q"]
    assert stated.profile_time == 4.0 and stated.profile_bin == 0.001 and stated.profile_defaults == []
    np.testing.assert_allclose(stated.profile_std, [0.0005] * 3)
    old = read_measured(
        write(
            tmp_path,
            HEADER
            + runout_rows()
            + "".join(f"q,quartz,6.0,0.02,profile,{x},{h},\n" for x, h in ((0.01, 0.03), (0.02, 0.01), (0.04, 0.0))),
            name="old.csv",
        )
    )["q"]
    assert old.profile_std is None and old.profile_read_at is None and old.profile_bin_width is None
    assert old.profile_time == 3.5  # the end of the runout record
    assert old.profile_bin == pytest.approx(0.015)  # the median spacing of its x points
    assert "not stated: the end of the runout record" in old.profile_defaults[0]
    assert "15 mm (not stated: the spacing of its x points)" in old.profile_defaults[1]


def test_profile_read_after_the_simulated_window_is_refused(tmp_path):
    column = read_measured(write(tmp_path, READ_HEADER + runout_rows(extra=",,") + profile_rows(read_at="5")))["q"]
    assert column.collapse_case(0.5, 0.5, duration_over_tstar=5.0).duration_over_tstar == 5.0
    with pytest.raises(CaseError, match=r"m.csv, line 9, column 'read_at'.*t/t\* = 5, after the simulated window"):
        column.collapse_case(0.5, 0.5, duration_over_tstar=4.0)


OWN_HEADER = "column,material,aspect_ratio,L_i,kind,x,value,std,grain_diameter,density,solid_fraction\n"


def own_rows(material="glass", own=("0.0004", "2500", "0.6")):
    """The quartz curve's runout rows as a column of `material`, with the cells of its own fields."""
    rows = runout_rows().splitlines()
    return "".join(row.replace(",quartz,", f",{material},") + "," + ",".join(own) + "\n" for row in rows)


def test_a_material_of_your_own_is_given_by_its_grain_diameter_density_and_solid_fraction(tmp_path):
    column = load_column(write(tmp_path, OWN_HEADER + own_rows()))
    material = column.material_properties
    assert (material.name, material.diameter, material.density, material.solid_fraction) == ("glass", 4e-4, 2500, 0.6)
    assert column.collapse_case(0.5, 0.5).material == material and column.measured_diameter == 4e-4


@pytest.mark.parametrize(
    "material, own, where",
    [
        ("glass", ("0.0004", "", "0.6"), r"line 2, column 'material': unknown material 'glass'.*missing: \['density'"),
        ("glass", ("", "", ""), r"unknown material 'glass'.*missing: \['grain_diameter', 'density', 'solid_fraction'"),
        ("glass", ("0.0004", "2500", "1.2"), r"line 2, column 'solid_fraction': .*below 1"),
        ("glass", ("0.0004", "-5", "0.6"), r"line 2, column 'density': .*positive"),
        ("quartz", ("", "2500", ""), r"line 2, column 'density': 'quartz' is a material of the table"),
    ],
)
def test_a_material_of_your_own_missing_a_property_or_renaming_the_tables(tmp_path, material, own, where):
    path = write(tmp_path, OWN_HEADER + own_rows(material, own))
    with pytest.raises(MeasuredDataError, match=where) as info:
        read_measured(path)
    assert str(path) in str(info.value)


def test_a_material_of_your_own_is_one_material_per_column(tmp_path):
    rows = own_rows().splitlines()
    rows[2] = rows[2].replace(",2500,", ",2400,")
    with pytest.raises(MeasuredDataError, match=r"line 4, column 'density': 2400 differs from 2500 on line 2"):
        read_measured(write(tmp_path, OWN_HEADER + "\n".join(rows) + "\n"))


# -- how the runout was read (runout_method): stated per column, else the config's ---------------------------
METHOD_HEADER = "column,material,aspect_ratio,L_i,kind,x,value,std,read_at,bin_width,runout_method\n"


def test_runout_method_is_kept_and_resolved_over_the_config(tmp_path):
    """A column states how its runout was read; its runs are read by that method with the config's other
    runout settings. An old file states none: the config's method, said so."""
    stated = load_column(write(tmp_path, METHOD_HEADER + runout_rows(extra=",,,connected_front_reached")))
    configured = {"method": "dense_front_reached", "n_leading": 4}
    assert stated.runout_method == "connected_front_reached" and stated.runout_defaults(configured) == []
    assert stated.runout_reading(configured) == RunoutMethod("connected_front_reached", n_leading=4)
    old = load_column("data/measured/quartz_a6.csv")
    assert old.runout_method is None and old.runout_reading(configured) == RunoutMethod.from_config(configured)
    assert old.runout_defaults(configured) == ["runout read by dense_front_reached (not stated: the config's `runout`)"]


def test_a_written_column_keeps_its_runout_method(tmp_path):
    """write_measured_csv (the synthetic and LIGGGHTS data's writer) states the reading; read back the same."""
    column = replace(load_column("data/measured/quartz_a6.csv"), runout_method="connected_front")
    write_measured_csv([column], tmp_path / "out.csv")
    assert load_column(tmp_path / "out.csv").runout_method == "connected_front"


@pytest.mark.parametrize(
    "rows, where",
    [
        (runout_rows(extra=",,,dense"), r"line 2, column 'runout_method': 'dense' is not a runout method"),
        (
            runout_rows(extra=",,,dense_front") + profile_rows().replace("\n", ",dense_front\n"),
            r"line 9, column 'runout_method': .*runout rows only",
        ),
        (
            runout_rows(extra=",,,dense_front").replace("2.0,4.2,,,,dense_front", "2.0,4.2,,,,"),
            r"line 5, column 'runout_method': missing here.*every runout row or on none",
        ),
        (
            runout_rows(extra=",,,dense_front").replace("2.0,4.2,,,,dense_front", "2.0,4.2,,,,connected_front"),
            r"line 5, column 'runout_method': 'connected_front' differs from 'dense_front' on line 2",
        ),
    ],
)
def test_a_bad_runout_method_names_file_line_and_column(tmp_path, rows, where):
    path = write(tmp_path, METHOD_HEADER + rows)
    with pytest.raises(MeasuredDataError, match=where) as info:
        read_measured(path)
    assert str(path) in str(info.value)
