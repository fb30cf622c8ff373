"""Full-factorial design over the DEM contact parameters (Jiang et al. 2024, section 2.4).

Each factor takes `n_levels` evenly spaced values in [low, high] (the paper: 7 levels of friction
mu and restitution e in [0.3, 0.9]), every combination is one DEM run, and the centre point is
run again with another packing seed: 7 x 7 + 1 = 50 runs. All factorial runs share one packing
seed, so differences between design points are due to (mu, e) alone (common random numbers); the
replicated centre measures how much a different packing moves the response (pure error).

Factors are coded x = (value - centre) / half_range, in [-1, 1] (paper: (mu - 0.6) / 0.3).

For three or more factors (a calibrated model with a mechanism parameter) a full factorial of 7
levels is 343+ runs; the face-centred central composite design (`face_centred_ccd`) fits the same
quadratic surface from 2^k corners, 2k face centres and the replicated centre (k = 3: 15 + r runs);
`three_level_factorial` adds the 3^k - 2^k - 2k - 1 points it lacks (k = 3: the 12 edge midpoints),
so the same DEM runs give both designs (k = 3: 27 + r runs, the GNS route's cost at r = 3).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from dem.atomic import atomic_path

if TYPE_CHECKING:
    from calibration.measured_column import MeasuredColumn
    from dem.case import CollapseCase


class DesignError(ValueError):
    """A design setting is unusable; the message names it."""


@dataclass(frozen=True)
class Factor:
    """A design factor: a CollapseCase field name and its bounds (low < high)."""

    name: str
    low: float
    high: float

    def __post_init__(self):
        if not self.low < self.high:
            raise DesignError(f"factor {self.name}: low ({self.low}) must be below high ({self.high})")

    @property
    def centre(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def half_range(self) -> float:
        return 0.5 * (self.high - self.low)

    def code(self, value: ArrayLike) -> np.ndarray | float:
        """Natural units -> coded [-1, 1] (an array for an array, a float for a scalar)."""
        return (np.asarray(value, float) - self.centre) / self.half_range

    def decode(self, coded: ArrayLike) -> np.ndarray | float:
        """Coded [-1, 1] -> natural units (an array for an array, a float for a scalar)."""
        return self.centre + np.asarray(coded, float) * self.half_range


FACTORS = (Factor("friction", 0.3, 0.9), Factor("restitution", 0.3, 0.9))


def factors_from_config(doe_config: dict) -> tuple[Factor, ...]:
    """Factors from the config's doe section: {friction: [low, high], restitution: [low, high]}."""
    return tuple(Factor(f.name, *map(float, doe_config.get(f.name, (f.low, f.high)))) for f in FACTORS)


def design_from_config(doe_config: dict) -> pd.DataFrame:
    """The design table from the config's doe section (levels, centre_replicates, seed, bounds)."""
    return full_factorial(
        factors_from_config(doe_config),
        doe_config.get("levels", 7),
        doe_config.get("centre_replicates", 1),
        doe_config.get("seed", 0),
    )


def centre_run_id(design: pd.DataFrame) -> str:
    """run_id of the factorial (not replicated) run at the centre of the design."""
    coded = design[[c for c in design.columns if c.startswith("x_")]].abs().sum(axis=1)
    return str(design.loc[(coded < 1e-9) & (design["replicate"] == 0), "run_id"].iloc[0])


def full_factorial(
    factors: Sequence[Factor] = FACTORS, n_levels: int = 7, centre_replicates: int = 1, seed: int = 0
) -> pd.DataFrame:
    """The design table, one row per DEM run.

    Columns: run_id ("run_00", ...), one column per factor (natural units) and x_<factor> (coded),
    seed (packing seed: `seed` for the factorial, seed + k for the k-th centre replicate), and
    replicate (0 for the factorial runs, k for the centre replicates). n_levels must be odd so that
    the centre is a factorial point that the replicates repeat.
    """
    if not isinstance(n_levels, int) or n_levels < 3 or n_levels % 2 == 0:
        raise DesignError(f"n_levels must be an odd integer >= 3 (the centre is a design point), got {n_levels!r}")
    if not isinstance(centre_replicates, int) or centre_replicates < 0:
        raise DesignError(f"centre_replicates must be a non-negative integer, got {centre_replicates!r}")
    # round so that 0.3 + k * 0.1 prints and compares as 0.4, not 0.39999999999999997
    grids = [np.round(np.linspace(f.low, f.high, n_levels), 12) for f in factors]
    points = list(itertools.product(*grids)) + [tuple(f.centre for f in factors)] * centre_replicates
    replicate = [0] * (len(points) - centre_replicates) + list(range(1, centre_replicates + 1))
    table = pd.DataFrame(points, columns=[f.name for f in factors])
    for f in factors:
        table[f"x_{f.name}"] = np.round(f.code(table[f.name]), 12)
    table["seed"] = [seed + k for k in replicate]
    table["replicate"] = replicate
    width = len(str(len(table) - 1))
    table.insert(0, "run_id", [f"run_{k:0{width}d}" for k in range(len(table))])
    return table


def face_centred_ccd(factors: Sequence[Factor], centre_replicates: int = 3, seed: int = 0) -> pd.DataFrame:
    """The face-centred central composite design (alpha = 1: every run within the bounds), one row
    per DEM run, in the columns of `full_factorial`.

    Rows: the 2^k corners (coded +-1), the 2k face centres (one factor at +-1, the others at 0), the
    centre (replicate 0) and `centre_replicates` more centre runs (replicate 1, 2, ...). Packing seed
    `seed` for every non-replicate run (common random numbers), seed + j for the j-th replicate.
    k = 2 gives the 3 x 3 design of `full_factorial(n_levels=3)`, in another order.
    """
    factors = tuple(factors)
    if len(factors) < 2 or not all(isinstance(f, Factor) for f in factors):
        raise DesignError(f"a central composite design needs at least 2 Factor objects, got {factors!r}")
    names = [f.name for f in factors]
    if len(set(names)) != len(names):
        raise DesignError(f"factor names must differ, got {names}")
    if not isinstance(centre_replicates, int) or centre_replicates < 0:
        raise DesignError(f"centre_replicates must be a non-negative integer, got {centre_replicates!r}")
    if not isinstance(seed, (int, np.integer)):
        raise DesignError(f"seed must be an integer, got {seed!r}")
    k = len(factors)
    corners = [list(point) for point in itertools.product((-1.0, 1.0), repeat=k)]
    faces = [[level if j == i else 0.0 for j in range(k)] for i in range(k) for level in (-1.0, 1.0)]
    coded = np.array(corners + faces + [[0.0] * k] * (1 + centre_replicates))
    replicate = [0] * (len(coded) - centre_replicates) + list(range(1, centre_replicates + 1))
    # round so that decoded bounds and centres print and compare as the numbers the user gave
    table = pd.DataFrame({f.name: np.round(f.decode(coded[:, i]), 12) for i, f in enumerate(factors)})
    for i, f in enumerate(factors):
        table[f"x_{f.name}"] = coded[:, i]
    table["seed"] = [int(seed) + j for j in replicate]
    table["replicate"] = replicate
    width = len(str(len(table) - 1))
    table.insert(0, "run_id", [f"run_{j:0{width}d}" for j in range(len(table))])
    return table


def three_level_factorial(factors: Sequence[Factor], centre_replicates: int = 3, seed: int = 0) -> pd.DataFrame:
    """The 3-level full factorial over `factors` (3^k points and `centre_replicates` centre runs),
    one row per DEM run, in the columns of `face_centred_ccd` plus `ccd`: the face-centred CCD's
    rows first, exactly as `face_centred_ccd` gives them (ccd True), then the 3^k points it lacks
    (ccd False; run ids continue, packing `seed`), so the CCD is a subset of the same runs.
    """
    ccd = face_centred_ccd(factors, centre_replicates, seed)
    factors = tuple(factors)
    coded_columns = [f"x_{f.name}" for f in factors]
    in_ccd = {tuple(point) for point in ccd[coded_columns].to_numpy()}
    points = [p for p in itertools.product((-1.0, 0.0, 1.0), repeat=len(factors)) if p not in in_ccd]
    rest = np.array(points, float).reshape(len(points), len(factors))  # k = 2: none
    extra = pd.DataFrame({f.name: np.round(f.decode(rest[:, i]), 12) for i, f in enumerate(factors)})
    for i, f in enumerate(factors):
        extra[f"x_{f.name}"] = rest[:, i]
    extra["seed"], extra["replicate"] = int(seed), 0
    table = pd.concat([ccd.drop(columns="run_id"), extra], ignore_index=True)
    width = max(len(str(len(table) - 1)), len(str(len(ccd) - 1)))
    run_ids = ccd["run_id"].tolist() + [f"run_{j:0{width}d}" for j in range(len(ccd), len(table))]
    table.insert(0, "run_id", run_ids)
    table["ccd"] = [True] * len(ccd) + [False] * len(extra)
    return table


def design_cases(design: pd.DataFrame, measured: MeasuredColumn, **case_fields: Any) -> dict[str, CollapseCase]:
    """{run_id: CollapseCase} for a design on a measured column (calibration.measured_column.MeasuredColumn).

    case_fields: further CollapseCase fields shared by every run (size_scale, duration_over_tstar...).
    """
    factor_names = [c[2:] for c in design.columns if c.startswith("x_")]
    cases = {}
    for row in design.itertuples(index=False):
        values = {name: float(getattr(row, name)) for name in factor_names}
        cases[row.run_id] = measured.collapse_case(**values, seed=int(row.seed), name=row.run_id, **case_fields)
    return cases


def write_design(path: str | os.PathLike, design: pd.DataFrame) -> None:
    with atomic_path(path) as tmp:
        design.to_csv(tmp, index=False)


def read_design(path: str | os.PathLike) -> pd.DataFrame:
    return pd.read_csv(path)
