"""Candidate mechanisms the paper's DEM model (friction mu, restitution e) leaves out.

Each candidate is one small plug-in class behind one interface (`Mechanism`): a single physical
parameter, "off" at `off_value`, that `case_fields` turns into CollapseCase fields of the builtin
engine (dem/, docs/dem.md "Candidate mechanisms"; each checked against a known answer in
tests/test_mechanisms.py). The diagnosis (calibration/diagnosis.py) adds one candidate at a time to
the base model and asks whether the data want it.

`bounds` is the box the diagnosis searches; `hidden_range` is the magnitude range the hidden-effect
tests and benchmark draw from. It is stated for the coarse-grained test columns (quartz, L_i =
0.02 m, a = 1 and 2, size_scale 4-5, runout to t/t* = 5) and chosen so that the effect on the
data is several times the noise: below it the base model absorbs the effect (measured: sidewall
friction 0.055 or rolling friction 0.12 changed the best base fit's BIC by less than 10), and no
diagnosis, ours included, can then name it.

The parameters are chosen so that the effect on the runout is roughly proportional to them (the
emulator then needs few runs):
- cohesion is a Bond number Bo = pull-off force of a mean pair / weight of a mean grain
  = 1.5 pi w (d/4) / (rho g pi d^3 / 6) = 2.25 w / (rho g d^2); the same Bo means the same
  physics for any material and grain size, w (J/m^2) itself does not;
- basal friction is designed and emulated on a log scale: the runout grows steeply as the floor
  friction falls towards zero and hardly changes between 0.5 and 1;
- the gate is described by its slowness 1/v (s/m): the time it takes to clear a column of height H
  is H/v, so the delay it causes grows linearly in 1/v, and 0 is the paper's instant removal.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import ClassVar

from dem.case import GRAVITY, CollapseCase

# The base model's parameters and the box they are calibrated in (the paper's DoE range, section 2.4).
BASE_PARAMETERS = ("friction", "restitution")
BASE_BOUNDS = ((0.3, 0.9), (0.3, 0.9))


# A fit that leaves a mechanism this close to its off value (a fraction of its range) has it off: the
# model is then the one without it at another point, and its gain in fit is no evidence for it.
# Found on LIGGGHTS data (basal friction 0.23, where "gate lift" won at gate slowness 0 by ΔBIC 38):
# docs/experiments/diagnosis.md, "2026-11-30: another solver's data (LIGGGHTS)".
OFF_TOLERANCE = 0.01


class MechanismError(ValueError):
    """An unknown candidate name or a parameter value outside what the candidate allows."""


@dataclass(frozen=True)
class Mechanism:
    """One candidate: a single parameter (`parameter`, in `unit`) added to the base model."""

    name: str  # the diagnosis' `cause` when this candidate is named
    parameter: str  # name of its parameter in reports
    unit: str
    bounds: tuple[float, float]  # search box of the diagnosis
    hidden_range: tuple[float, float]  # magnitudes drawn by the hidden-effect tests
    description: str
    log_scale: bool = False  # design and emulator work in log(parameter)
    # the values the parameter takes for dry grains of 0.1-1 mm (this project's materials) and why;
    # a fitted value outside is an effective parameter of the curve it fits, not the material's
    plausible: tuple[float, float] = (-math.inf, math.inf)
    plausible_source: str = ""

    def case_fields(self, value: float, case: CollapseCase) -> dict:
        """CollapseCase fields that switch the mechanism on at `value` for `case` (its base fields)."""
        raise NotImplementedError

    def off_value(self, friction: float, restitution: float) -> float:
        """The parameter value at which the extended model is the base model at (mu, e)."""
        setting = self.off_setting()
        return {"friction": friction, "restitution": restitution}[setting] if isinstance(setting, str) else setting

    def off_setting(self) -> float | str:
        """off_value as data: a number, or the base parameter ("friction" or "restitution") whose
        value it takes (a GNS dataset's metadata records it: gns.dataset.build_dataset)."""
        return 0.0

    def switched_on(self, parameters: Mapping[str, float]) -> bool:
        """Whether fitted `parameters` ({name: value}, friction and restitution among them) put this
        mechanism's parameter beyond OFF_TOLERANCE of its range from its off value."""
        off = self.off_value(parameters["friction"], parameters["restitution"])
        low, high = self.bounds
        return abs(parameters[self.parameter] - off) > OFF_TOLERANCE * (high - low)

    def is_plausible(self, value: float) -> bool:
        """Whether `value` lies in the physically plausible range (its ends included)."""
        low, high = self.plausible
        return low - 1e-12 <= value <= high + 1e-12

    def plausibility(self, value: float) -> str:
        """In words: whether `value` lies in the physically plausible range, with its source."""
        low, high = self.plausible
        span = f"[{low:g}, {high:g}] {self.unit}".rstrip(" -")
        if self.is_plausible(value):
            return f"{self.parameter} = {value:.3g} lies in the physical range {span} ({self.plausible_source})"
        return (
            f"{self.parameter} = {value:.3g} lies outside the physical range {span} ({self.plausible_source}): "
            "an effective parameter, not a physical one"
        )

    def check(self, value: float) -> float:
        low, high = self.bounds
        if not low - 1e-12 <= value <= high + 1e-12:
            raise MechanismError(
                f"{self.name}: {self.parameter} = {value} outside its bounds [{low}, {high}] {self.unit}"
            )
        return float(value)


class RollingResistance(Mechanism):
    engine_field: ClassVar[str] = "rolling_friction"  # the CollapseCase field it switches on

    def case_fields(self, value: float, case: CollapseCase) -> dict:
        return {"rolling_friction": self.check(value)}


class Cohesion(Mechanism):
    engine_field: ClassVar[str] = "cohesion_energy"  # the CollapseCase field it switches on

    def case_fields(self, value: float, case: CollapseCase) -> dict:
        return {"cohesion_energy": cohesion_energy_from_bond(self.check(value), case)}


class BasalFriction(Mechanism):
    engine_field: ClassVar[str] = "friction_base"  # the CollapseCase field it switches on

    def case_fields(self, value: float, case: CollapseCase) -> dict:
        return {"friction_base": self.check(value)}

    def off_setting(self) -> str:
        return "friction"  # the base model's floor has the grains' friction


@dataclass(frozen=True)
class SidewallFriction(Mechanism):
    engine_field: ClassVar[str] = "sidewall_friction"
    channel_width: float = 0.01  # m, width of the quasi-2D channel (fixed, not fitted)

    def case_fields(self, value: float, case: CollapseCase) -> dict:
        return {"sidewall_friction": self.check(value), "channel_width": self.channel_width}


class GateLift(Mechanism):
    engine_field: ClassVar[str] = "gate_lift_speed"  # the CollapseCase field it switches on

    def case_fields(self, value: float, case: CollapseCase) -> dict:
        slowness = self.check(value)
        return {"gate_lift_speed": 1.0 / slowness if slowness > 0 else 0.0}


def cohesion_energy_from_bond(bond: float, case: CollapseCase) -> float:
    """Work of adhesion w (J/m^2) whose mean-pair pull-off force is `bond` mean-grain weights."""
    return bond * case.density * GRAVITY * case.diameter**2 / 2.25


def bond_from_cohesion_energy(cohesion_energy: float, case: CollapseCase) -> float:
    return 2.25 * cohesion_energy / (case.density * GRAVITY * case.diameter**2)


def candidate_mechanisms(channel_width: float = 0.01) -> dict[str, Mechanism]:
    """The five candidates by name, in report order."""
    candidates = (
        RollingResistance(
            "rolling_resistance",
            "rolling_friction",
            "-",
            (0.0, 0.4),
            (0.15, 0.35),
            "type-C (EPSD2) rolling resistance mu_r: a torque up to mu_r R* |Fn| opposes rolling",
            plausible=(0.0, 0.3),
            plausible_source="DEM calibrations of round to angular sands with this model, Ai et al. 2011, "
            "Powder Technol. 206, 269; Wensrich & Katterfeld 2012, Powder Technol. 217, 409",
        ),
        Cohesion(
            "cohesion",
            "bond_number",
            "-",
            (0.0, 60.0),
            (15.0, 45.0),
            "JKR pull-off cohesion, as a Bond number (pull-off force / grain weight)",
            plausible=(0.0, 1.0),
            plausible_source="dry grains coarser than ~0.1 mm flow freely, their Bond number below 1: "
            "Castellanos 2005, Adv. Phys. 54, 263",
        ),
        BasalFriction(
            "basal_friction",
            "friction_base",
            "-",
            (0.02, 1.0),
            (0.03, 0.08),
            "floor friction different from the grains' friction (base model: floor mu = grain mu)",
            log_scale=True,
            plausible=(0.1, 1.0),
            plausible_source="wall-friction tests of sand on floors from polished glass to sandpaper, "
            "Schulze 2008, Powders and Bulk Solids",
        ),
        SidewallFriction(
            "sidewall_friction",
            "sidewall_friction",
            "-",
            (0.0, 0.3),
            (0.08, 0.2),
            f"Coulomb drag of the front/back walls of a {channel_width * 1e3:g} mm quasi-2D channel",
            channel_width=channel_width,
            plausible=(0.1, 0.6),
            plausible_source="wall-friction tests of sand and beads on glass or acrylic walls, Schulze 2008, "
            "Powders and Bulk Solids",
        ),
        GateLift(
            "gate_lift",
            "gate_slowness",
            "s/m",
            (0.0, 4.0),
            (1.0, 3.3),
            "gate lifted at finite speed v (parameter 1/v; 0 = removed at once, as in the paper)",
            plausible=(0.0, 2.0),
            plausible_source="a lab gate clears the column at 0.5 m/s or faster, against its free fall of "
            "~1 m/s; Sarlin et al. 2021, Phys. Rev. E 104, 064904, vary it",
        ),
    )
    return {m.name: m for m in candidates}


# The materials the built-in plausible ranges are stated for: the paper's dry quartz and copper
# grains (dem.case.MATERIALS). Another material takes them as defaults unless the config states its own.
PLAUSIBLE_STATED_FOR = ("quartz", "copper")


def check_plausible_range(mechanism: Mechanism, low: float, high: float) -> None:
    """MechanismError unless [low, high] is an interval that meets the mechanism's bounds: a range
    the calibration can never reach would call every answer effective by construction."""
    b_low, b_high = mechanism.bounds
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise MechanismError(f"{mechanism.name}: plausible range [{low}, {high}] is not an interval [low, high]")
    if high < b_low or low > b_high:
        unit = "" if mechanism.unit == "-" else f" {mechanism.unit}"
        raise MechanismError(
            f"{mechanism.name}: plausible range [{low:g}, {high:g}]{unit} lies outside the "
            f"{mechanism.parameter} bounds [{b_low:g}, {b_high:g}]{unit} the calibration searches"
        )


def plausible_for(mechanism: Mechanism, material: str, ranges: Mapping[str, Mapping[str, Mapping]]) -> Mechanism:
    """`mechanism` with the plausible range of its parameter for `material`: ranges[material][name]
    ({range: [low, high], source}) where the config states one, else the built-in range, whose
    source then says it is a default for a material it was not stated for."""
    stated = ranges.get(material, {}).get(mechanism.name)
    if stated is not None:
        low, high = map(float, stated["range"])
        check_plausible_range(mechanism, low, high)
        return replace(mechanism, plausible=(low, high), plausible_source=str(stated["source"]))
    if material in PLAUSIBLE_STATED_FOR:
        return mechanism
    return replace(
        mechanism,
        plausible_source=f"the default for dry grains of 0.1-1 mm, as {material!r} states none "
        f"(calibration.plausible_ranges): {mechanism.plausible_source}",
    )


def get_mechanisms(names: Sequence[str] | None = None, channel_width: float = 0.01) -> list[Mechanism]:
    """The candidates named in `names` (all five when None), in the order given."""
    known = candidate_mechanisms(channel_width)
    if names is None:
        return list(known.values())
    unknown = [n for n in names if n not in known]
    if unknown:
        raise MechanismError(f"unknown candidate mechanism(s) {unknown}; known: {list(known)}")
    return [known[n] for n in names]
