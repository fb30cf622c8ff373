"""The geometries of a campaign's GNS dataset, given by hand (config key calibration.campaign_geometry).

Unstated, a campaign's dataset cycles its cases through the campaign's own columns
(pipeline.cases.campaign_templates), so a column added to the campaign moves most of its cases to
other columns: the dataset is run anew and its GNS trained again. Given by hand, the dataset cycles
through every stated aspect ratio with every stated L_i, whatever the campaign holds: a column on
those geometries adds no case, and its GNS rollouts start from the first frames of the dataset's
runs of its own geometry. A column off them is refused before any job (check_campaign_geometry):
outside the stated range the GNS would extrapolate, and between the stated geometries no run of the
dataset starts its rollouts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from calibration.measured import first_lines
from calibration.measured_column import MeasuredColumn
from dem.case import CaseError, CollapseCase, check_grains_across
from dem.grid import ConfigError

KEY = "calibration.campaign_geometry"
DEFAULT_DURATION = CollapseCase.__dataclass_fields__["duration_over_tstar"].default  # t*, a case's default


def given_geometries(config: dict, name: str) -> list[tuple[float, float]] | None:
    """[(aspect_ratio, L_i in m)] of campaign `name`'s GNS dataset as calibration.campaign_geometry
    gives it, every aspect ratio with every L_i in the order given; None where it is not given."""
    given = config["calibration"].get("campaign_geometry", {}).get(name)
    if given is None:
        return None
    return [(float(a), float(L_i)) for a in given["aspect_ratio"] for L_i in given["L_i"]]


def fixed_by_config(config: dict, name: str) -> dict | None:
    """{model, channel_width}: the model of campaign `name`'s GNS dataset where the config alone makes
    that dataset, else None. So it is where its geometries are given by hand and its model fixed
    (calibration.model other than auto, in its whole range: calibration.box full, or no diagnosis):
    then its cases take their model from this record in their case-table rows, not from the
    model.json each diagnosis of a grown campaign writes anew, and a column added on the given
    geometries reruns neither the dataset nor its GNS (a model.json rewritten unchanged would date
    them all)."""
    section = config["calibration"]
    if given_geometries(config, name) is None or section["model"] == "auto":
        return None
    if section["box"] != "full" and config["diagnosis"]["enabled"]:
        return None
    return {"model": section["model"], "channel_width": config["diagnosis"]["channel_width"]}


def given_duration(config: dict, name: str, base_row: dict) -> float:
    """The simulated time (t*) of the cases of campaign `name`'s hand-given dataset: its
    duration_over_tstar, else that of base_row (the first GNS dataset's first case)."""
    given = config["calibration"]["campaign_geometry"][name]
    return float(given.get("duration_over_tstar", base_row.get("duration_over_tstar", DEFAULT_DURATION)))


def check_campaign_geometry(
    config: dict, campaigns: Sequence[str], columns: dict[str, dict[str, MeasuredColumn]], base_row: dict | None
) -> None:
    """Every entry of calibration.campaign_geometry names a campaign; where that campaign has a GNS
    route (base_row: the first GNS dataset's first case, None without one) its geometries pass the
    size guard at diagnosis.size_scale, calibration.gns_cases gives each (else each column) a run, and every
    column of the campaign (columns: {campaign: {column name: column}}) lies on one of them and within
    their duration. ConfigError naming the key, and for a column the file, line and CSV column."""
    section = config["calibration"]
    for name in campaigns if base_row is not None else ():
        if name not in section.get("campaign_geometry", {}) and section["gns_cases"] < len(columns[name]):
            raise ConfigError(
                f"config key calibration.gns_cases: {section['gns_cases']} cases cannot cover the "
                f"{len(columns[name])} columns of campaign {name!r} (each needs a run of its own: its first frames "
                "start that column's rollouts)"
            )
    for name in section.get("campaign_geometry", {}):
        if name not in campaigns:
            raise ConfigError(
                f"config key {KEY}.{name}: {name!r} is not a campaign (the `measured` entries of several columns: "
                f"{list(campaigns)})"
            )
        if base_row is None:
            continue
        geometries = given_geometries(config, name)
        if section["gns_cases"] < len(geometries):
            raise ConfigError(
                f"config key calibration.gns_cases: {section['gns_cases']} cases cannot cover the {len(geometries)} "
                f"geometries of {KEY}.{name} (each needs a run of its own: its first frames start the rollouts of "
                "a column of that geometry)"
            )
        size_scale = config["diagnosis"]["size_scale"]
        material = next(iter(columns[name].values())).material_properties
        for L_i in config["calibration"]["campaign_geometry"][name]["L_i"]:
            try:
                where = f"{KEY}.{name}.L_i (at diagnosis.size_scale, the campaign's)"
                check_grains_across(L_i, material, size_scale, config["dem"]["min_grains_across"], where)
            except CaseError as exc:
                raise ConfigError(f"config key {exc}") from exc
        duration = given_duration(config, name, base_row)
        lines = first_lines(config["measured"][name])
        for column in columns[name].values():
            where = f"config key {KEY}.{name}: {column.source}, line {lines[column.name]}"
            for csv_column, value, levels in (
                ("aspect_ratio", column.aspect_ratio, [a for a, _ in geometries]),
                ("L_i", column.L_i, [L for _, L in geometries]),
            ):
                _check_on_levels(f"{where}, column {csv_column!r}", column.name, csv_column, value, levels, name)
            if column.t_over_tstar[-1] > duration * (1 + 1e-9):
                raise ConfigError(
                    f"{where}, column 'x': column {column.name!r} is measured to t/t* = {column.t_over_tstar[-1]:g}, "
                    f"past the {duration:g} t* its campaign's GNS dataset simulates; raise "
                    f"{KEY}.{name}.duration_over_tstar"
                )


def _check_on_levels(where: str, column: str, key: str, value: float, levels: list[float], name: str) -> None:
    """The column's `key` value is one of the dataset's levels, else a ConfigError saying whether it
    lies outside their range or between them."""
    if any(math.isclose(value, level, rel_tol=1e-9) for level in levels):
        return
    low, high = min(levels), max(levels)
    if value < low * (1 - 1e-9) or value > high * (1 + 1e-9):
        why = (
            f"lies outside the range of its campaign's GNS dataset, {key} in [{low:g}, {high:g}]: the GNS would "
            "extrapolate"
        )
    else:
        why = (
            f"lies between the geometries of its campaign's GNS dataset ({key} "
            f"[{', '.join(f'{level:g}' for level in sorted(set(levels)))}]): no run of the dataset starts its rollouts"
        )
    raise ConfigError(
        f"{where}: column {column!r} ({key} = {value:g}) {why}; add {value:g} to {KEY}.{name}.{key} (the dataset is "
        "run anew), or leave the key out to cycle the dataset through the campaign's own columns"
    )
