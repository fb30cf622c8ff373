"""The calibrated model: the set of parameters being calibrated, one value shared by the diagnosis'
design runs, the GNS dataset and checkpoint, the DoE design, the optimisers and the validations.

`Model()` is the paper's base model (friction mu, restitution e); `Model(mechanism)` adds one
candidate mechanism (calibration/mechanisms.py) and its parameter, `Model(first, second)` a pair of
them, each with its own parameter. A model knows its parameters' names, their box (physically
plausible ranges, some on a log scale) and how a parameter point theta [p] becomes a DEM case of a
measured column. Its name is "base", the mechanism's, or the pair's joined by "+"
(`model_named` reads it back).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from calibration.emulator import ParameterBox
from calibration.mechanisms import BASE_BOUNDS, BASE_PARAMETERS, Mechanism, MechanismError, get_mechanisms

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


PAIR_SEPARATOR = "+"  # joins the mechanisms' names in a pair's name


@dataclass(frozen=True, init=False)
class Model:
    """The base model (friction, restitution), or the base model plus one or two candidate mechanisms."""

    mechanisms: tuple[Mechanism, ...]

    def __init__(self, *mechanisms: Mechanism | None):
        chosen = tuple(m for m in mechanisms if m is not None)
        names = [m.name for m in chosen]
        if len(set(names)) < len(names):
            raise MechanismError(f"a model holds each mechanism once, not {names}")
        object.__setattr__(self, "mechanisms", chosen)

    @property
    def mechanism(self) -> Mechanism | None:
        """The one mechanism of the base model plus one (None for the base model); the diagnosis,
        which adds one candidate at a time, reads this. MechanismError for a pair."""
        if len(self.mechanisms) > 1:
            raise MechanismError(f"{self.name} holds {len(self.mechanisms)} mechanisms, not one")
        return self.mechanisms[0] if self.mechanisms else None

    @property
    def name(self) -> str:
        return PAIR_SEPARATOR.join(m.name for m in self.mechanisms) or "base"

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return BASE_PARAMETERS + tuple(m.parameter for m in self.mechanisms)

    @property
    def bounds(self) -> np.ndarray:
        """[p, 2] (low, high) of every parameter."""
        return np.array(BASE_BOUNDS + tuple(m.bounds for m in self.mechanisms), float)

    @property
    def box(self) -> ParameterBox:
        return ParameterBox(self.bounds, (False,) * len(BASE_BOUNDS) + tuple(m.log_scale for m in self.mechanisms))

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
        switch each mechanism on at its parameter, theta[2], theta[3]."""
        case = case.replace(friction=float(theta[0]), restitution=float(theta[1]))
        for k, mechanism in enumerate(self.mechanisms, start=len(BASE_PARAMETERS)):
            case = case.replace(**mechanism.case_fields(float(theta[k]), case))
        return case

    def embed_base(self, base_theta: ArrayLike) -> np.ndarray:
        """Base-model points [n, 2] as points [n, p] of this model (every mechanism at its off value)."""
        base_theta = np.atleast_2d(np.asarray(base_theta, float))
        points = [self.embed(Model(), theta) for theta in base_theta]
        return np.array(points, float).reshape(len(base_theta), self.n_parameters)

    def embed(self, other: Model, theta: ArrayLike) -> np.ndarray:
        """A point theta [q] of `other`, a model whose mechanisms this one holds, as a point [p] of
        this model: each mechanism `other` lacks at its off value at theta's (mu, e)."""
        theta = np.asarray(theta, float)
        values = dict(zip(other.parameter_names, theta))
        missing = [m.name for m in other.mechanisms if m.name not in {n.name for n in self.mechanisms}]
        if missing:
            raise MechanismError(f"{self.name} does not hold {missing} of {other.name}")
        mu, e = theta[: len(BASE_PARAMETERS)]
        point = list(theta[: len(BASE_PARAMETERS)])
        for m in self.mechanisms:
            off = float(np.clip(m.off_value(mu, e), *m.bounds))
            point.append(float(values.get(m.parameter, off)))
        return np.array(point, float)


def model_named(name: str, channel_width: float = 0.01) -> Model:
    """The model of a name: "base", a candidate mechanism's name, or two joined by "+"
    ("sidewall_friction+rolling_resistance"); MechanismError naming the unknown ones."""
    if name == "base":
        return Model()
    return Model(*get_mechanisms(name.split(PAIR_SEPARATOR), channel_width))
