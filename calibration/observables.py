"""What a DEM run is compared with the measurement on: the observables of the measured columns.

Observables (`Observables`): for every measured column, the runout L* at its measured t/t* points
and, when a deposit profile was measured, the deposit height (m) at its measured x points, read
by dem.runout.profile_at the way the file says the measurement was read: at its t/t* (default:
the last runout t/t*) with its bin width in metres (default: the spacing of its x points). The
runout is read as the file says the measurement was read (its `runout_method`), else by the
configured dem.runout method (`Observables.runout`), the same as every other stage's
(MeasuredColumn.runout_reading).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from calibration.measured_column import MeasuredColumn
from calibration.objective import simulated_runout_at
from dem.runout import RunoutMethod, profile_at

if TYPE_CHECKING:
    from dem.trajectory import Trajectory


class LibraryError(ValueError):
    """A run library does not fit the columns, models or settings it is used with."""


# -- what is compared ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Observables:
    """The simulated numbers compared with the measurement, in one flat order [q].

    Per column, in column order: runout L* at its t/t* points (read by `runout`, the config's
    dem.runout.RunoutMethod, with the column's stated method in place of its own), then (if
    measured) deposit height (m) at its profile x points.
    """

    columns: tuple[MeasuredColumn, ...]
    runout: RunoutMethod = field(default_factory=RunoutMethod)

    def __post_init__(self):
        object.__setattr__(self, "columns", tuple(self.columns))
        object.__setattr__(self, "runout", RunoutMethod.from_config(self.runout))
        if not self.columns:
            raise LibraryError("no measured columns to observe")
        names = [c.name for c in self.columns]
        if len(set(names)) != len(names):
            raise LibraryError(f"measured column names repeat: {names}")

    @property
    def labels(self) -> list[tuple[str, str, float]]:
        """(column name, "runout" | "profile", t/t* or x (m)) for every output."""
        out = []
        for c in self.columns:
            out += [(c.name, "runout", float(t)) for t in c.t_over_tstar]
            if c.profile_x is not None:
                out += [(c.name, "profile", float(x)) for x in c.profile_x]
        return out

    @property
    def size(self) -> int:
        return len(self.labels)

    @property
    def column_index(self) -> np.ndarray:
        names = [c.name for c in self.columns]
        return np.array([names.index(label[0]) for label in self.labels])

    @property
    def kind(self) -> np.ndarray:
        return np.array([label[1] for label in self.labels])

    @property
    def x(self) -> np.ndarray:
        return np.array([label[2] for label in self.labels])

    @property
    def measured(self) -> np.ndarray:
        parts = []
        for c in self.columns:
            parts.append(c.runout)
            if c.profile_x is not None:
                parts.append(c.profile_height)
        return np.concatenate(parts).astype(float)

    @property
    def measured_std(self) -> np.ndarray:
        """[q] stated noise std (L* or m); NaN where the file gives none."""
        parts = []
        for c in self.columns:
            parts.append(c.runout_std if c.runout_std is not None else np.full(len(c.runout), np.nan))
            if c.profile_x is not None:
                parts.append(c.profile_std if c.profile_std is not None else np.full(len(c.profile_x), np.nan))
        return np.concatenate(parts).astype(float)

    def reading(self, column: MeasuredColumn) -> RunoutMethod:
        """How a run of `column` is read: its stated method, else the configured one."""
        return column.runout_reading(self.runout)

    @property
    def stated_methods(self) -> dict[str, str]:
        """{column name: runout method} of the columns whose file states a method other than the
        configured one (the only columns whose runs are read otherwise)."""
        return {c.name: self.reading(c).method for c in self.columns if self.reading(c).method != self.runout.method}

    def signature(self) -> dict:
        """What a library built for these observables must match (geometry, observation points and
        how the runout is read off a run)."""
        return (
            {
                "columns": [[c.name, c.material, c.aspect_ratio, c.L_i] for c in self.columns],
                "labels": [list(label) for label in self.labels],
                "runout": self.runout.to_config(),
            }
            # a column read by another method than the configured one (only then, so that the
            # libraries of columns read the configured way keep their signature)
            | ({"runout_methods": self.stated_methods} if self.stated_methods else {})
            # how each profile is read (only where there is one, so runout-only libraries keep their signature)
            | (
                {"profiles": {c.name: [c.profile_time, c.profile_bin] for c in self.columns if c.profile_x is not None}}
                if any(c.profile_x is not None for c in self.columns)
                else {}
            )
        )

    def from_trajectories(self, trajectories: Sequence[Trajectory], columns: Sequence[int] | None = None) -> np.ndarray:
        """Observables of one simulated trajectory per column: [q] for all columns, or, with
        `columns` (column indices, the trajectories in that order), only those columns' outputs in
        flat order (the entries of `column_index` in `columns`)."""
        columns = range(len(self.columns)) if columns is None else columns
        parts = []
        for j, trajectory in zip(columns, trajectories, strict=True):
            column = self.columns[j]
            t, runout = self.reading(column).curve(trajectory)
            parts.append(simulated_runout_at(t, runout, column))
            if column.profile_x is not None:
                # read as the measurement states it was read: same time, same bins in metres
                parts.append(profile_at(trajectory, column.profile_time, column.profile_x, column.profile_bin))
        return np.concatenate(parts)
