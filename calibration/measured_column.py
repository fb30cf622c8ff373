"""One measured column collapse: the record every score, design run and validation works on, and
the scaling law its runout is held against.

MeasuredColumn holds a column's material, geometry (a, L_i), runout curve L*(t/t*) and, optionally,
its final deposit profile, each with its noise level, and how they were read: `collapse_case` gives
the column's DEM case, `runout_reading` resolves how a simulated run of it is read.
calibration/measured.py reads columns from the measured-data CSV (its schema is described there).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from dem.case import MATERIALS, CaseError, CollapseCase, Material
from dem.runout import RunoutMethod


@dataclass(frozen=True)
class MeasuredColumn:
    """One measured collapse.

    t_over_tstar [K] (-, increasing) with runout [K] = L* (-) and runout_std [K] (-) or None;
    profile_x [P] (m) and profile_height [P] (m), or None when no deposit profile was measured,
    with profile_std [P] (m) or None, and how it was read: profile_read_at (t/t*) and
    profile_bin_width (m), None where the file does not say (`profile_time`, `profile_bin` give the
    values used then, `profile_defaults` says which were defaulted); runout_method: how the runout
    was read (a dem.runout method name), None where the file does not say (`runout_reading` gives
    the reading the simulated runs are scored with, `runout_defaults` says when it was defaulted).
    """

    name: str
    material: str
    aspect_ratio: float
    L_i: float  # m
    t_over_tstar: np.ndarray
    runout: np.ndarray
    runout_std: np.ndarray | None = None
    profile_x: np.ndarray | None = None
    profile_height: np.ndarray | None = None
    source: str = ""
    profile_std: np.ndarray | None = None
    profile_read_at: float | None = None
    profile_bin_width: float | None = None
    profile_line: int | None = None  # line of the file's first profile row, for error messages
    grain_diameter: float | None = None  # m, of the measured grains; None: the material's
    density: float | None = None  # kg/m^3, of a material not in dem.case.MATERIALS (None for one that is)
    solid_fraction: float | None = None  # -, likewise
    runout_method: str | None = None  # how the runout was read (dem.runout.METHODS); None: not stated

    @property
    def material_properties(self) -> Material:
        """The DEM material: the table's (dem.case.MATERIALS), else the file's own (its grain_diameter,
        density and solid_fraction)."""
        if self.material in MATERIALS:
            return MATERIALS[self.material]
        return Material(self.material, self.grain_diameter, self.density, self.solid_fraction)

    @property
    def measured_diameter(self) -> float:
        """Mean diameter (m) of the grains that were measured: the file's, else the material's."""
        return self.material_properties.diameter if self.grain_diameter is None else float(self.grain_diameter)

    @property
    def profile_time(self) -> float:
        """t/t* at which the profile was read: the file's read_at, else the last runout t/t*."""
        return float(self.t_over_tstar[-1]) if self.profile_read_at is None else float(self.profile_read_at)

    @property
    def profile_bin(self) -> float:
        """Bin width (m) the profile was read with: the file's bin_width, else the median spacing of
        the profile's x points, at least one real grain diameter (a narrower bin cannot hold a grain)."""
        if self.profile_bin_width is not None:
            return float(self.profile_bin_width)
        if self.profile_x is None:
            raise ValueError(f"column {self.name!r} has no profile")
        return max(float(np.median(np.diff(self.profile_x))), self.material_properties.diameter)

    @property
    def profile_defaults(self) -> list[str]:
        """What the file left unsaid about its profile reading, and the value used instead."""
        if self.profile_x is None:
            return []
        out = []
        if self.profile_read_at is None:
            out.append(f"read at t/t* = {self.profile_time:g} (not stated: the end of the runout record)")
        if self.profile_bin_width is None:
            out.append(f"bins of {self.profile_bin * 1e3:.3g} mm (not stated: the spacing of its x points)")
        return out

    def runout_reading(self, configured: RunoutMethod | dict | str | None) -> RunoutMethod:
        """How a simulated run of this column is read to be compared with it: the configured runout
        settings (the config's `runout` section), with the method the file states in place of the
        config's. The one place a column's reading is resolved, so every score reads it alike."""
        configured = RunoutMethod.from_config(configured)
        if self.runout_method is None:
            return configured
        return dataclasses.replace(configured, method=self.runout_method)

    def runout_defaults(self, configured: RunoutMethod | dict | str | None) -> list[str]:
        """What the file left unsaid about its runout reading, and the method used instead."""
        if self.runout_method is not None:
            return []
        return [f"runout read by {RunoutMethod.from_config(configured).method} (not stated: the config's `runout`)"]

    @property
    def H_i(self) -> float:
        """Initial column height (m)."""
        return self.aspect_ratio * self.L_i

    def collapse_case(self, friction: float, restitution: float, **case_fields: Any) -> CollapseCase:
        """The DEM case of this measured column (its material, a and L_i) at (mu, e).

        case_fields: any other CollapseCase field (size_scale for a coarse-grained counterpart,
        seed, ...). The simulated window must cover the last measured t/t*.
        """
        case = CollapseCase(
            material=self.material_properties,
            L_i=self.L_i,
            aspect_ratio=self.aspect_ratio,
            friction=friction,
            restitution=restitution,
            **case_fields,
        )
        if case.duration_over_tstar < self.t_over_tstar[-1]:
            raise CaseError(
                f"duration_over_tstar = {case.duration_over_tstar} ends before the last measured "
                f"t/t* = {self.t_over_tstar[-1]} of {self.name!r} ({self.source})"
            )
        if self.profile_x is not None and case.duration_over_tstar < self.profile_time:
            raise CaseError(
                f"{self.source}, line {self.profile_line}, column 'read_at': the profile of {self.name!r} is read at "
                f"t/t* = {self.profile_time:g}, after the simulated window ends (duration_over_tstar = "
                f"{case.duration_over_tstar:g})"
            )
        return case


def own_material_fields(material: Material) -> dict:
    """The MeasuredColumn fields that give `material` when it is not in dem.case.MATERIALS ({} when it is)."""
    if isinstance(material.to_config(), str):  # a material of the table goes by its name alone
        return {}
    return {"grain_diameter": material.diameter, "density": material.density, "solid_fraction": material.solid_fraction}
