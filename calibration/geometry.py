"""Does the measured column lie in the geometry a GNS was trained on? The checks of the GNS inverse
design (calibration.gns_objective, calibration.inverse) that need no model: the config's checks
(pipeline.config) run them on the case table before any job, without loading torch.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Collection

import numpy as np

from calibration.measured_column import MeasuredColumn
from dem.case import get_material

GEOMETRY_TOLERANCE = 0.05  # relative distance to the nearest training case that warns


class InverseDesignError(ValueError):
    """The inverse design cannot give a trustworthy optimum; the message says why."""


class GeometryWarning(UserWarning):
    """The measured column lies away from every column the GNS was trained on."""


def check_geometry(measured: MeasuredColumn, metadata: dict, training_attrs: list[dict]) -> dict:
    """Where the measured column lies relative to the GNS's training columns.

    training_attrs: attributes of the training trajectories. Returns {"distance": relative
    distance to the nearest training column in (aspect_ratio, L_i), "nearest": its (a, L_i)}.
    InverseDesignError for another material or a column outside the trained L_i/H_i range (the
    model refuses those inputs); GeometryWarning (with the distance) when no training column is
    within GEOMETRY_TOLERANCE.
    """
    materials = metadata.get("materials") or sorted({str(a["material"]) for a in training_attrs})
    if measured.material not in materials:
        raise InverseDesignError(
            f"measured column {measured.name!r} ({measured.source}) is {measured.material}; "
            f"the GNS was trained on {materials} only (it has no material input)"
        )
    ranges = metadata["parameter_ranges"]
    outside = []
    for key, value in (("L_i", measured.L_i), ("H_i", measured.H_i), ("aspect_ratio", measured.aspect_ratio)):
        low, high = ranges[key]
        if value < low * (1 - 1e-6) or value > high * (1 + 1e-6):
            off = (low - value) if value < low else (value - high)
            outside.append(
                f"{key} = {value:g} lies outside [{low:g}, {high:g}] (by {off:g}, {off / max(abs(value), 1e-12):.0%})"
            )
    if outside:
        raise InverseDesignError(
            f"measured column {measured.name!r} ({measured.source}) lies outside the geometry the GNS was trained "
            f"on: {'; '.join(outside)}; train the GNS on this geometry (a dataset with its material, aspect "
            "ratio and L_i)"
        )
    columns = np.array([[float(a["aspect_ratio"]), float(a["L_i"])] for a in training_attrs])
    target = np.array([measured.aspect_ratio, measured.L_i])
    relative = np.max(np.abs(columns - target) / target, axis=1)
    nearest = int(np.argmin(relative))
    distance = float(relative[nearest])
    if distance > GEOMETRY_TOLERANCE:
        warnings.warn(
            f"measured column {measured.name!r} (a = {measured.aspect_ratio:g}, L_i = {measured.L_i:g} m) "
            f"is {distance:.0%} away from the nearest training column (a = {columns[nearest, 0]:g}, "
            f"L_i = {columns[nearest, 1]:g} m): the GNS interpolates between geometries here",
            GeometryWarning,
            stacklevel=2,
        )
    return {"distance": distance, "nearest": columns[nearest].tolist()}


def nearest_dataset(measured: MeasuredColumn, rows: list[dict], datasets: Collection[str]) -> str:
    """The dataset (among `datasets`) whose training columns come nearest the measured one.

    rows: case-table rows (dem.grid) with dataset, split, material, aspect_ratio, L_i. Only datasets
    of the measured material count; the distance is the largest relative difference in (a, L_i).
    """
    best, best_distance = None, math.inf
    for row in rows:
        if row["dataset"] not in datasets or row["split"] != "train" or material_name(row) != measured.material:
            continue
        distance = max(
            abs(float(row["aspect_ratio"]) - measured.aspect_ratio) / measured.aspect_ratio,
            abs(float(row["L_i"]) - measured.L_i) / measured.L_i,
        )
        if distance < best_distance:
            best, best_distance = row["dataset"], distance
    if best is None:
        raise InverseDesignError(
            f"measured column {measured.name!r} ({measured.source}) is {measured.material}; "
            f"no GNS dataset among {sorted(datasets)} has {measured.material} training cases"
        )
    return best


def material_name(row: dict) -> str:
    """The name of a case-table row's material (a table name, or a mapping of a material's fields)."""
    return get_material(row["material"]).name


def check_geometry_of_dataset(measured: MeasuredColumn, rows: list[dict], dataset: str) -> dict:
    """check_geometry from case-table rows (before any DEM run): the dataset's parameter ranges
    over all its rows (as gns.dataset computes them) and its training rows as the training set."""
    mine = [dict(r, H_i=float(r["aspect_ratio"]) * float(r["L_i"])) for r in rows if r["dataset"] == dataset]
    ranges = {
        k: [min(float(r[k]) for r in mine), max(float(r[k]) for r in mine)] for k in ("L_i", "H_i", "aspect_ratio")
    }
    metadata = {"materials": sorted({material_name(r) for r in mine}), "parameter_ranges": ranges}
    return check_geometry(measured, metadata, [r for r in mine if r["split"] == "train"])
