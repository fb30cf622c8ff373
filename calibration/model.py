"""The calibrated model: the set of parameters being calibrated, one value shared by the diagnosis'
design runs, the GNS dataset and checkpoint, the DoE design, the optimisers and the validations.

`Model()` is the paper's base model (friction mu, restitution e); `Model(mechanism)` adds one
candidate mechanism (calibration/mechanisms.py) and its parameter. A model knows its parameters'
names, their box (physically plausible ranges, some on a log scale) and how a parameter point
theta [p] becomes a DEM case of a measured column.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from calibration.emulator import ParameterBox
from calibration.mechanisms import BASE_BOUNDS, BASE_PARAMETERS, Mechanism

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from calibration.measured_column import MeasuredColumn
    from dem.case import CollapseCase


class RunSettings(Protocol):
    """What a model's case reads of how the DEM is run (calibration.design_runs.SimulationSettings;
    named by its shape here so that this module imports nothing of the design runs, which import it)."""

    size_scale: float  # coarse-graining factor of the grains

    def duration_for(self, column: MeasuredColumn) -> float:
        """Simulated t/t* of a run of `column`."""
        ...


@dataclass(frozen=True)
class Model:
    """The base model (friction, restitution), or the base model plus one candidate mechanism."""

    mechanism: Mechanism | None = None

    @property
    def name(self) -> str:
        return "base" if self.mechanism is None else self.mechanism.name

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return BASE_PARAMETERS + (() if self.mechanism is None else (self.mechanism.parameter,))

    @property
    def bounds(self) -> np.ndarray:
        """[p, 2] (low, high) of every parameter."""
        extra = () if self.mechanism is None else (self.mechanism.bounds,)
        return np.array(BASE_BOUNDS + extra, float)

    @property
    def box(self) -> ParameterBox:
        extra = () if self.mechanism is None else (self.mechanism.log_scale,)
        return ParameterBox(self.bounds, (False,) * len(BASE_BOUNDS) + extra)

    @property
    def n_parameters(self) -> int:
        return len(self.parameter_names)

    def case(
        self, column: MeasuredColumn, theta: Sequence[float] | np.ndarray, settings: RunSettings, seed: int
    ) -> CollapseCase:
        """The CollapseCase of `column` at parameters theta [p] (mu, e[, mechanism parameter]),
        coarse-grained per settings."""
        case = column.collapse_case(
            float(theta[0]),
            float(theta[1]),
            size_scale=settings.size_scale,
            seed=seed,
            duration_over_tstar=settings.duration_for(column),
            output_interval=None,
            name=f"{column.name}:{self.name}",
        )
        return self.at(case, theta)

    def at(self, case: CollapseCase, theta: Sequence[float] | np.ndarray) -> CollapseCase:
        """`case` with this model's parameters theta [p]: friction, restitution and the fields that
        switch the mechanism on at theta[2]."""
        case = case.replace(friction=float(theta[0]), restitution=float(theta[1]))
        if self.mechanism is not None:
            case = case.replace(**self.mechanism.case_fields(float(theta[2]), case))
        return case

    def embed_base(self, base_theta: ArrayLike) -> np.ndarray:
        """Base-model points [n, 2] as points [n, p] of this model (mechanism at its off value)."""
        base_theta = np.atleast_2d(np.asarray(base_theta, float))
        if self.mechanism is None:
            return base_theta
        off = [self.mechanism.off_value(mu, e) for mu, e in base_theta]
        return np.column_stack([base_theta, np.clip(off, *self.mechanism.bounds)])
