"""Measured column-collapse data: the CSV reader and its checks; each column it reads becomes a
calibration.measured_column.MeasuredColumn.

Schema (full description and examples in data/measured/README.md). A CSV file in long format,
`#` lines are comments, one header line, then one row per measured value:

    column,material,aspect_ratio,L_i,kind,x,value,std
    quartz_a6,quartz,6.0,0.02,runout,0.5,0.3,
    quartz_a6,quartz,6.0,0.02,profile,0.035,0.012,

  column        name of the measured column (several columns may share one file)
  material      DEM material of the grains: a name of dem.case.MATERIALS, or a name of your own
                whose grain_diameter, density and solid_fraction the file gives
  aspect_ratio  a = H_i / L_i of the initial column (-)
  L_i           initial column length (m)
  kind          `runout`: x = t/t* (-), value = runout L* = (L - L_i)/L_i (-)
                `profile`: final deposit, x = distance from the left wall (m), value = height (m)
  std           optional noise level: standard deviation of `value`, same units; empty = unknown
  runout_method optional, runout rows: how the runout was read, a dem.runout method name
                (dem.runout.METHODS), one value per column (empty: not stated; the simulated runs
                are read by the config's `runout` method)
  read_at       optional, profile rows: t/t* at which the profile was read (empty: the last
                runout t/t*, the end of the runout record)
  bin_width     optional, profile rows: width (m) of the bins the profile was read with, the
                height being the highest point of grain in its strip (empty: the spacing of the x
                points, at least one grain diameter)
  grain_diameter optional: mean diameter (m) of the measured grains, one value per column (empty:
                the material's, dem.case.MATERIALS; say it when the data come from a sieve
                fraction of its own or from a coarse-grained simulation)
  density       kg/m^3, solid_fraction (-): a material not in dem.case.MATERIALS, one value per
                column, with its grain_diameter (empty for a material of the table)

The file is UTF-8 (a byte-order mark, as a spreadsheet's "CSV UTF-8" writes one, is read past) and
its delimiter is ','. Each column needs at least two runout points; material, aspect_ratio and L_i
must agree on every row of a column; L* is a plain ratio, not metres nor percent. Every error names
the file, the line and the CSV column that is wrong.
"""

from __future__ import annotations

import codecs
import csv
import math
import os
import warnings
from pathlib import Path

import numpy as np

from calibration.measured_column import MeasuredColumn
from calibration.scaling_laws import quasi_2d_runout
from dem.case import MATERIALS, CaseError, Material
from dem.runout import METHODS

REQUIRED_FIELDS = ("column", "material", "aspect_ratio", "L_i", "kind", "x", "value")
OPTIONAL_FIELDS = ("std", "read_at", "bin_width", "grain_diameter", "density", "solid_fraction", "runout_method")
# What a material of your own needs (one value per column): with the name, the dem.case.Material fields.
OWN_MATERIAL_FIELDS = ("grain_diameter", "density", "solid_fraction")
PROFILE_READING = ("read_at", "bin_width")  # how a profile was read: one value per column, or none
RUNOUT_READING = "runout_method"  # how the runout was read: one dem.runout method per column, or none
KINDS = ("runout", "profile")
MAX_L_I = 1.0  # m; a column length above this is almost surely given in mm or cm
OTHER_DELIMITERS = {";": "';'", "\t": "a tab"}  # how a spreadsheet may save a CSV, by the name a message gives


class MeasuredDataError(ValueError):
    """A measured-data file breaks the schema; the message names file, line and CSV column."""


class MeasuredDataWarning(UserWarning):
    """A measured-data file is readable but something in it looks physically doubtful."""


def read_measured(path: str | os.PathLike) -> dict[str, MeasuredColumn]:
    """Every measured column in the CSV file `path`, by name, in file order."""
    path = Path(path)
    if not path.is_file():
        raise MeasuredDataError(f"{path}: no such measured-data file")
    rows = _read_rows(path)
    columns: dict[str, list] = {}
    for line, row in rows:
        columns.setdefault(row["column"], []).append((line, row))
    if not columns:
        raise MeasuredDataError(f"{path}: no data rows after the header")
    return {name: _build_column(path, name, rows) for name, rows in columns.items()}


def first_lines(path: str | os.PathLike) -> dict[str, int]:
    """{column name: the line of its first row} of the file `path`, for messages that name a column's line."""
    lines: dict[str, int] = {}
    for line, row in _read_rows(Path(path)):
        lines.setdefault(row["column"], line)
    return lines


def check_one_material(path: str | os.PathLike) -> None:
    """Every column of the file `path` is of one material (a campaign calibrates one parameter set);
    MeasuredDataError naming the first row of the first column of another."""
    path = Path(path)
    first: tuple[int, dict] | None = None
    for line, row in _read_rows(path):
        if first is None:
            first = (line, row)
        elif row["material"] != first[1]["material"]:
            raise MeasuredDataError(
                f"{path}, line {line}, column 'material': column {row['column']!r} is of {row['material']!r}, "
                f"column {first[1]['column']!r} (line {first[0]}) of {first[1]['material']!r}: a campaign's "
                "columns are of one material (give each material an entry of its own)"
            )


def load_column(path: str | os.PathLike, name: str | None = None) -> MeasuredColumn:
    """The measured column `name` from `path`; name may be omitted when the file holds one column."""
    columns = read_measured(path)
    if name is None:
        if len(columns) != 1:
            raise MeasuredDataError(f"{path}: holds columns {list(columns)}; say which one")
        return next(iter(columns.values()))
    if name not in columns:
        raise MeasuredDataError(f"{path}: no measured column {name!r}; the file holds {list(columns)}")
    return columns[name]


# -- parsing -------------------------------------------------------------------------------------
def _read_rows(path: Path) -> list[tuple[int, dict]]:
    """(line number, {field: raw string}) for every data row; checks the header."""
    lines = _read_lines(path)
    content = [(n, text) for n, text in lines if text.strip() and not text.lstrip().startswith("#")]
    if not content:
        raise MeasuredDataError(f"{path}: empty file (no header line)")
    header_line, header_text = content[0]
    _check_delimiter(path, header_line, header_text)
    header = [name.strip() for name in next(csv.reader([header_text]))]
    missing = [name for name in REQUIRED_FIELDS if name not in header]
    if missing:
        raise MeasuredDataError(
            f"{path}, line {header_line}: header lacks column(s) {missing}; "
            f"the schema needs {list(REQUIRED_FIELDS)} (+ optional {list(OPTIONAL_FIELDS)})"
        )
    unknown = [name for name in header if name not in REQUIRED_FIELDS + OPTIONAL_FIELDS]
    if unknown:
        raise MeasuredDataError(
            f"{path}, line {header_line}: unknown column(s) {unknown}; known: {list(REQUIRED_FIELDS + OPTIONAL_FIELDS)}"
        )
    duplicated = sorted({name for name in header if header.count(name) > 1})
    if duplicated:
        raise MeasuredDataError(f"{path}, line {header_line}: column(s) {duplicated} appear twice")
    rows = []
    for line, text in content[1:]:
        cells = [cell.strip() for cell in next(csv.reader([text]))]
        if len(cells) != len(header):
            raise MeasuredDataError(f"{path}, line {line}: {len(cells)} fields, the header has {len(header)}")
        rows.append((line, dict(zip(header, cells))))
    return rows


def _read_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of every line of `path`, read as UTF-8; a byte-order mark at the start (a
    spreadsheet's "CSV UTF-8") is read past, a byte that is not UTF-8 is an error naming its line."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            return list(enumerate(handle, start=1))
    except UnicodeDecodeError:
        raise _not_utf8(path) from None


def _not_utf8(path: Path) -> MeasuredDataError:
    """The error for a file that is not UTF-8, naming the first line that is not and its byte."""
    raw = path.read_bytes().removeprefix(codecs.BOM_UTF8)
    for line, text in enumerate(raw.splitlines(keepends=True), start=1):
        try:
            text.decode("utf-8")
        except UnicodeDecodeError as exc:
            byte = text[exc.start : exc.start + 1]
            return MeasuredDataError(
                f"{path}, line {line}: byte 0x{byte.hex()} (byte {exc.start + 1} of the line) is not UTF-8 (read as "
                f"Latin-1 it is {byte.decode('latin-1')!r}: the file was saved in another encoding); save it as "
                "UTF-8 (a spreadsheet's CSV UTF-8 format)"
            )
    return MeasuredDataError(f"{path}: not UTF-8; save it as UTF-8 (a spreadsheet's CSV UTF-8 format)")


def _check_delimiter(path: Path, line: int, header_text: str) -> None:
    """The schema's delimiter is ','. A header without one, split by ';' (as a spreadsheet saves a CSV
    in a locale whose decimal mark is ',') or by tabs, is an error naming the delimiter it uses."""
    if "," in header_text:
        return
    for delimiter, name in OTHER_DELIMITERS.items():
        if delimiter in header_text:
            raise MeasuredDataError(
                f"{path}, line {line}: the header's fields are separated by {name}; the schema's delimiter is ',' "
                "(and its decimal mark '.'): save the file as CSV with ',' between fields"
            )


def _number(path, line, field, text, allow_empty=False) -> float:
    if text == "" and allow_empty:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        raise MeasuredDataError(f"{path}, line {line}, column {field!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise MeasuredDataError(f"{path}, line {line}, column {field!r}: {text!r} is not finite")
    return value


def _build_column(path: Path, name: str, rows: list) -> MeasuredColumn:
    first_line, first = rows[0]
    if not name:
        raise MeasuredDataError(f"{path}, line {first_line}, column 'column': empty column name")
    material = first["material"]
    if not material:
        raise MeasuredDataError(f"{path}, line {first_line}, column 'material': empty material name")
    aspect_ratio = _number(path, first_line, "aspect_ratio", first["aspect_ratio"])
    L_i = _number(path, first_line, "L_i", first["L_i"])
    if aspect_ratio <= 0:
        raise MeasuredDataError(
            f"{path}, line {first_line}, column 'aspect_ratio': must be positive, got {aspect_ratio}"
        )
    if not 0 < L_i <= MAX_L_I:
        raise MeasuredDataError(
            f"{path}, line {first_line}, column 'L_i': {L_i} is not a column length in metres "
            f"(0 < L_i <= {MAX_L_I} m; was it given in mm?)"
        )
    series = {kind: [] for kind in KINDS}
    grains = []  # (line, grain_diameter or NaN) of every row
    own = {field: [] for field in OWN_MATERIAL_FIELDS[1:]}  # density, solid_fraction (or NaN) of every row
    methods = []  # runout_method (or "") of every runout row
    for line, row in rows:
        for field, expected in (("material", material),):
            if row[field] != expected:
                raise MeasuredDataError(
                    f"{path}, line {line}, column {field!r}: {row[field]!r} differs from "
                    f"{expected!r} on line {first_line} for the same measured column {name!r} (two columns of one "
                    "name? give each its own)"
                )
        for field, expected in (("aspect_ratio", aspect_ratio), ("L_i", L_i)):
            if _number(path, line, field, row[field]) != expected:
                raise MeasuredDataError(
                    f"{path}, line {line}, column {field!r}: {row[field]} differs from "
                    f"{expected} on line {first_line} for the same measured column {name!r} (two columns of one "
                    "name? give each its own)"
                )
        kind = row["kind"]
        if kind not in KINDS:
            raise MeasuredDataError(f"{path}, line {line}, column 'kind': {kind!r} is not one of {list(KINDS)}")
        x = _number(path, line, "x", row["x"])
        if kind == "runout" and row["value"].endswith("%"):
            raise MeasuredDataError(
                f"{path}, line {line}, column 'value': {row['value']!r} is a percentage; give L* = (L - L_i)/L_i "
                "as a fraction (250% is 2.5)"
            )
        value = _number(path, line, "value", row["value"])
        std = _number(path, line, "std", row.get("std", ""), allow_empty=True)
        reading = {f: _number(path, line, f, row.get(f, ""), allow_empty=True) for f in PROFILE_READING}
        for field, value_ in reading.items():
            if kind == "runout" and not math.isnan(value_):
                raise MeasuredDataError(
                    f"{path}, line {line}, column {field!r}: a runout row is read at its own t/t* (x); "
                    f"{field} applies to profile rows only: leave it empty"
                )
        method = row.get(RUNOUT_READING, "")
        if method and kind != "runout":
            raise MeasuredDataError(
                f"{path}, line {line}, column {RUNOUT_READING!r}: says how a runout was read; it applies to "
                "runout rows only: leave it empty"
            )
        if method and method not in METHODS:
            raise MeasuredDataError(
                f"{path}, line {line}, column {RUNOUT_READING!r}: {method!r} is not a runout method "
                f"(dem.runout: {list(METHODS)}); leave it empty to read the runs by the config's `runout`"
            )
        if kind == "runout":
            methods.append(method)
        if not math.isnan(reading["read_at"]) and reading["read_at"] <= 0:
            raise MeasuredDataError(
                f"{path}, line {line}, column 'read_at': a profile is read at t/t* > 0, got {reading['read_at']}"
            )
        grain = _number(path, line, "grain_diameter", row.get("grain_diameter", ""), allow_empty=True)
        if not (math.isnan(grain) or 0 < grain <= 0.1):
            raise MeasuredDataError(
                f"{path}, line {line}, column 'grain_diameter': {grain} is not a grain diameter in metres "
                "(0 < d <= 0.1 m)"
            )
        grains.append((line, grain))
        for field in own:
            own[field].append(_number(path, line, field, row.get(field, ""), allow_empty=True))
        diameter = grain if material not in MATERIALS else MATERIALS[material].diameter
        # the units check: a bin holds at least a real grain
        if not math.isnan(reading["bin_width"]) and diameter > 0 and reading["bin_width"] < diameter:
            raise MeasuredDataError(
                f"{path}, line {line}, column 'bin_width': {reading['bin_width']} m is below one grain diameter "
                f"of {material} ({diameter:g} m): no bin that narrow holds a grain (was it given in mm?)"
            )
        if x < 0:
            raise MeasuredDataError(f"{path}, line {line}, column 'x': must be >= 0, got {x}")
        if not math.isnan(std) and std <= 0:
            raise MeasuredDataError(
                f"{path}, line {line}, column 'std': a noise level of {std} is not a "
                "standard deviation (zero would claim an exact measurement); leave the cell "
                "empty if unknown"
            )
        series[kind].append((line, x, value, std, reading))

    grain = _one_value(
        path, name, grains, [g for _, g in grains], "grain_diameter", "", "one measured column has one grain size"
    )
    properties = {
        field: _one_value(path, name, grains, values, field, "", "one measured column has one material")
        for field, values in own.items()
    }
    _check_material(path, name, first_line, material, {"grain_diameter": grain, **properties})
    t, runout, std = _series(path, name, series["runout"], "t/t*", min_points=2)
    _all_or_none(path, name, series["runout"], [p[3] for p in series["runout"]], "std", "runout")
    method = _one_value(
        path, name, series["runout"], methods, RUNOUT_READING, "runout", f"one runout of {name!r} is read one way"
    )
    profile, reading = None, {f: math.nan for f in PROFILE_READING}
    if series["profile"]:
        profile = _series(path, name, series["profile"], "profile x", min_points=2)
        negative = np.flatnonzero(profile[1] < 0)
        if negative.size:
            raise MeasuredDataError(
                f"{path}, line {series['profile'][negative[0]][0]}, column 'value': deposit height must be >= 0 m"
            )
        _all_or_none(path, name, series["profile"], [p[3] for p in series["profile"]], "std", "profile")
        for field in PROFILE_READING:
            values = [p[4][field] for p in series["profile"]]
            reading[field] = _one_value(
                path, name, series["profile"], values, field, "profile", f"one profile of {name!r} is read one way"
            )
    column = MeasuredColumn(
        name=name,
        material=material,
        aspect_ratio=aspect_ratio,
        L_i=L_i,
        t_over_tstar=t,
        runout=runout,
        runout_std=None if np.isnan(std).all() else std,
        profile_x=None if profile is None else profile[0],
        profile_height=None if profile is None else profile[1],
        source=str(path),
        profile_std=None if profile is None or np.isnan(profile[2]).all() else profile[2],
        profile_read_at=None if math.isnan(reading["read_at"]) else reading["read_at"],
        profile_bin_width=None if math.isnan(reading["bin_width"]) else reading["bin_width"],
        profile_line=series["profile"][0][0] if series["profile"] else None,
        grain_diameter=None if math.isnan(grain) else grain,
        **{field: None if math.isnan(value) else value for field, value in properties.items()},
        runout_method=method or None,
    )
    _check_runout_units(path, column, series["runout"][0][0])
    return column


def _check_material(path: Path, name: str, line: int, material: str, given: dict[str, float]) -> None:
    """A material of the table takes the table's density and solid fraction (its grain_diameter may
    differ: a sieve fraction of its own); any other material needs all of OWN_MATERIAL_FIELDS."""
    stated = [field for field in OWN_MATERIAL_FIELDS[1:] if not math.isnan(given[field])]
    if material in MATERIALS:
        if stated:
            raise MeasuredDataError(
                f"{path}, line {line}, column {stated[0]!r}: {material!r} is a material of the table "
                f"(dem.case.MATERIALS: {MATERIALS[material]}); leave {stated} empty, or give your material a name "
                "of its own"
            )
        return
    missing = [field for field in OWN_MATERIAL_FIELDS if math.isnan(given[field])]
    if missing:
        raise MeasuredDataError(
            f"{path}, line {line}, column 'material': unknown material {material!r} (the table, dem.case.MATERIALS: "
            f"{sorted(MATERIALS)}); a material of your own needs {list(OWN_MATERIAL_FIELDS)} on the rows of column "
            f"{name!r} (missing: {missing})"
        )
    try:
        Material(material, given["grain_diameter"], given["density"], given["solid_fraction"])
    except CaseError as exc:
        field = "solid_fraction" if "solid_fraction" in str(exc) else "density"
        raise MeasuredDataError(f"{path}, line {line}, column {field!r}: {exc}") from None


def _all_or_none(path: Path, name: str, points: list, values: list[float | str], field: str, kind: str) -> None:
    """A field given on some `kind` rows of a column and not on others is an error naming the first gap
    (a missing number is NaN, a missing name "")."""
    missing = [v == "" if isinstance(v, str) else math.isnan(v) for v in values]
    if any(missing) and not all(missing):
        line = points[missing.index(True)][0]
        rows = f"{kind} rows" if kind else "rows"
        raise MeasuredDataError(
            f"{path}, line {line}, column {field!r}: missing here but given on other {rows} of "
            f"{name!r}; give it on every {kind + ' ' if kind else ''}row or on none"
        )


def _one_value(
    path: Path, name: str, points: list, values: list[float | str], field: str, kind: str, why: str
) -> float | str:
    """The one value a field has on every `kind` row of a column (NaN, or "" for a name: on none);
    given on some rows only, or differing between rows, is an error naming the line."""
    _all_or_none(path, name, points, values, field, kind)
    for (line, *_), value in zip(points, values):
        if value != values[0] and not (isinstance(value, float) and math.isnan(value)):
            raise MeasuredDataError(
                f"{path}, line {line}, column {field!r}: {_cell(value)} differs from {_cell(values[0])} on line "
                f"{points[0][0]}: {why}"
            )
    return values[0]


def _cell(value: float | str) -> str:
    """A parsed cell as a message shows it: a number by %g, a name quoted."""
    return repr(value) if isinstance(value, str) else f"{value:g}"


def _series(path, name, points, what, min_points):
    """(x [K], value [K], std [K]) from parsed points, checking count and increasing x."""
    if len(points) < min_points:
        where = f", line {points[0][0]}" if points else ""
        raise MeasuredDataError(
            f"{path}{where}: measured column {name!r} has {len(points)} {what} point(s); "
            f"at least {min_points} are needed (one point cannot constrain a curve)"
        )
    lines = [p[0] for p in points]
    x, value, std = (np.array([p[k] for p in points], float) for k in (1, 2, 3))
    for k in range(1, len(x)):
        if x[k] <= x[k - 1]:
            raise MeasuredDataError(
                f"{path}, line {lines[k]}, column 'x': {what} = {x[k]} does not increase "
                f"(previous row of {name!r} has {x[k - 1]}); list points in increasing order"
            )
    return x, value, std


def _check_runout_units(path, column: MeasuredColumn, line: int) -> None:
    """Catch runout given in metres (L or L - L_i) or in percent instead of the dimensionless L*.

    A metre-valued runout of a lab column is a few L_i, so every value is below 0.5 and, divided by
    L_i, it becomes a plausible L* for the column's aspect ratio, while read as L* it is far too
    short. Only late curves (t/t* >= 2, front near its final position) are judged for metres: earlier
    the front has not gone far and small values are genuine. A percent-valued runout, divided by 100,
    is a plausible L* (at least a quarter of the final runout the scaling gives), so read as L* it is
    at least 25x that final runout, which no front reaches at any time (a runout more than 4x away
    from it already warns): curves of any length are judged for percent.
    """
    expected = quasi_2d_runout(column.aspect_ratio)
    reached = float(np.max(column.runout))
    if reached > 4 * expected and expected / 4 <= reached / 100 <= 4 * expected + 1:
        raise MeasuredDataError(
            f"{path}, line {line}, column 'value': runout of {column.name!r} peaks at {reached:g}, yet a column of "
            f"a = {column.aspect_ratio:g} runs out to L* ~ {expected:.2g}; divided by 100 it would be "
            f"{reached / 100:.3g}. The values look like percent; give L* = (L - L_i)/L_i as a fraction instead "
            "(250% is 2.5)"
        )
    if column.t_over_tstar[-1] < 2.0:
        return
    if reached < 0.5 and reached < expected / 4 and expected / 4 <= reached / column.L_i <= 4 * expected + 1:
        raise MeasuredDataError(
            f"{path}, line {line}, column 'value': runout of {column.name!r} peaks at {reached:g}, yet a column of "
            f"a = {column.aspect_ratio:g} runs out to L* ~ {expected:.2g}; divided by L_i = {column.L_i:g} m it "
            f"would be {reached / column.L_i:.3g}. The values look like metres (L or L - L_i); "
            "give L* = (L - L_i)/L_i instead"
        )
    if not expected / 4 <= reached <= 4 * expected:
        warnings.warn(
            f"{path}: runout of {column.name!r} peaks at L* = {reached:g}, far from the L* ~ "
            f"{expected:.2g} expected for a = {column.aspect_ratio:g} (Lube et al. 2005); check units",
            MeasuredDataWarning,
            stacklevel=3,
        )
