"""A granular column-collapse case, described once.

The paper's set-up (Jiang et al. 2024, section 3.1): a 500 x 350 mm two-dimensional box, a column
of L_i x H_i grains held against the left wall by a gate at x = L_i, removed at t = 0. Every engine
(builtin, LIGGGHTS, MFIX) and every downstream stage reads its physics from a `CollapseCase`.

Units are SI throughout: metres, kilograms, seconds.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from dem.fields import from_mapping

if TYPE_CHECKING:
    import numpy as np

GRAVITY = 9.81  # m/s^2


class CaseError(ValueError):
    """A case field has a value no simulation can use; the message names the field."""


@dataclass(frozen=True)
class Material:
    """Grain material: mean diameter (m), solid density (kg/m^3), column solid (volume) fraction."""

    name: str
    diameter: float
    density: float
    solid_fraction: float

    def __post_init__(self):
        for key in ("diameter", "density", "solid_fraction"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise CaseError(f"material {self.name!r}: {key} must be a positive finite number, got {value!r}")
        if self.solid_fraction >= 1:
            raise CaseError(f"material {self.name!r}: solid_fraction must be below 1, got {self.solid_fraction}")

    @classmethod
    def from_attrs(cls, attrs: dict) -> Material:
        """The material a trajectory was run with, from its HDF5 attributes (CollapseCase.physical_parameters)."""
        return cls(
            str(attrs["material"]),
            float(attrs["material_diameter"]),
            float(attrs["material_density"]),
            float(attrs["material_solid_fraction"]),
        )

    def to_config(self) -> str | dict:
        """How a config or a case row names it: a table material by its name, any other by its fields."""
        return self.name if MATERIALS.get(self.name) == self else dataclasses.asdict(self)


# Table 1 of the paper (after Biroun et al. 2023).
MATERIALS = {
    "quartz": Material("quartz", diameter=425e-6, density=2650.0, solid_fraction=0.58),
    "copper": Material("copper", diameter=325e-6, density=8960.0, solid_fraction=0.50),
}


def sphere_mass(density: float, diameter: float | np.ndarray) -> float | np.ndarray:
    """Mass (kg) of spheres of `diameter` (m; a float or an array [N]) and `density` (kg/m^3). The cube
    is two products, not a power: numpy's vector power is compiled per instruction set and may round
    otherwise on another machine, where the products round the same everywhere."""
    return density * math.pi * (diameter * diameter * diameter) / 6.0


def get_material(spec: str | dict | Material) -> Material:
    """A material from its name ("quartz", "copper"), a mapping of its fields, or a Material."""
    if isinstance(spec, Material):
        return spec
    if isinstance(spec, str):
        if spec not in MATERIALS:
            raise CaseError(
                f"material: unknown material {spec!r}; known: {sorted(MATERIALS)} "
                "(or give a mapping with name, diameter, density, solid_fraction)"
            )
        return MATERIALS[spec]
    if isinstance(spec, dict):
        missing = {"name", "diameter", "density", "solid_fraction"} - set(spec)
        if missing:
            raise CaseError(f"material: custom material is missing {sorted(missing)}")
        material = Material(**{k: spec[k] for k in ("name", "diameter", "density", "solid_fraction")})
        if material.name in MATERIALS and material != MATERIALS[material.name]:  # one name, one material
            raise CaseError(
                f"material: {material.name!r} is a material of the table ({MATERIALS[material.name]}); "
                "give your material another name"
            )
        return material
    raise CaseError(f"material: expected a name or a mapping, got {type(spec).__name__}")


@dataclass(frozen=True)
class CollapseCase:
    """One DEM column-collapse case.

    Contact law (every engine): linear spring-dashpot, normal stiffness `normal_stiffness` (N/m),
    tangential stiffness `tangential_stiffness_ratio` * kn with history and Coulomb limit
    `friction`, normal damping from `restitution`, tangential damping
    `tangential_damping_ratio` * normal damping. `*_wall` values apply to particle-wall contacts.
    """

    material: Material
    L_i: float  # initial column length (m)
    aspect_ratio: float  # a = H_i / L_i
    friction: float  # mu, particle-particle
    restitution: float  # e, particle-particle
    friction_wall: float | None = None  # None: follows `friction` (see resolved_friction_wall)
    restitution_wall: float | None = None
    seed: int = 0
    size_scale: float = 1.0  # coarse-graining factor on the grain diameter
    polydispersity: float = 0.10  # diameters uniform in d (1 +- polydispersity)
    box_width: float = 0.500  # m
    box_height: float = 0.350  # m
    normal_stiffness: float = 1000.0  # kn (N/m)
    tangential_stiffness_ratio: float = 2.0 / 7.0
    tangential_damping_ratio: float = 0.5
    dt_over_contact_time: float = 1.0 / 50.0
    # Candidate mechanisms beyond the paper's model, each off by default (docs/dem.md, "Candidate mechanisms"):
    rolling_friction: float = 0.0  # mu_r of a type-C (EPSD2) rolling resistance
    cohesion_energy: float = 0.0  # w (J/m^2): pull-off force 1.5 pi w R* while in contact
    friction_base: float | None = None  # floor friction; None: follows the wall friction
    sidewall_friction: float = 0.0  # mu of the front/back walls of a quasi-2D channel
    channel_width: float = 0.01  # m, width of that channel (used when sidewall_friction > 0)
    gate_lift_speed: float = 0.0  # m/s of the gate's lower edge; 0: the gate vanishes at t = 0
    duration_over_tstar: float = 4.0  # simulated collapse time in units of t*
    output_interval: float | None = None  # s between output frames; None: t* / 25
    name: str = field(default="", compare=False)

    def __post_init__(self):
        object.__setattr__(self, "material", get_material(self.material))
        positive = (
            "L_i",
            "aspect_ratio",
            "size_scale",
            "box_width",
            "box_height",
            "normal_stiffness",
            "tangential_stiffness_ratio",
            "dt_over_contact_time",
            "duration_over_tstar",
        )
        for key in positive:
            _check_finite(key, getattr(self, key))
            if getattr(self, key) <= 0:
                raise CaseError(f"{key} must be positive, got {getattr(self, key)}")
        for key in (
            "friction",
            "friction_wall",
            "friction_base",
            "tangential_damping_ratio",
            "polydispersity",
            "rolling_friction",
            "cohesion_energy",
            "sidewall_friction",
            "gate_lift_speed",
        ):
            if getattr(self, key) is None:
                continue
            _check_finite(key, getattr(self, key))
            if getattr(self, key) < 0:
                raise CaseError(f"{key} must be >= 0, got {getattr(self, key)}")
        for key in ("restitution", "restitution_wall"):
            value = getattr(self, key)
            if value is None:
                continue
            _check_finite(key, value)
            if not 0 < value <= 1:
                raise CaseError(f"{key} must lie in (0, 1], got {value}")
        _check_finite("channel_width", self.channel_width)
        if self.channel_width < self.diameter:
            raise CaseError(f"channel_width = {self.channel_width} m is narrower than a grain ({self.diameter:.3g} m)")
        if self.polydispersity >= 0.5:
            raise CaseError(f"polydispersity must be below 0.5, got {self.polydispersity}")
        if self.dt_over_contact_time > MAX_DT_OVER_CONTACT_TIME:
            raise CaseError(
                f"dt_over_contact_time = {self.dt_over_contact_time} is above the stable bound "
                f"{MAX_DT_OVER_CONTACT_TIME} (time step must resolve a contact in >= 10 steps)"
            )
        if self.output_interval is not None:
            _check_finite("output_interval", self.output_interval)
            if not self.time_step < self.output_interval <= self.t_star * self.duration_over_tstar:
                raise CaseError(
                    f"output_interval = {self.output_interval} s must exceed the time step "
                    f"({self.time_step:.3g} s) and not the simulated duration"
                )
        if not isinstance(self.seed, int) or self.seed < 0:
            raise CaseError(f"seed must be a non-negative integer, got {self.seed!r}")
        if self.L_i > 0.8 * self.box_width:
            raise CaseError(
                f"L_i = {self.L_i} m leaves no room to flow in a {self.box_width} m box (at most 80% of box_width)"
            )
        if self.H_i * FILL_HEIGHT_FACTOR > self.box_height:
            raise CaseError(
                f"column of height {self.H_i:.4g} m (aspect_ratio x L_i) does not "
                f"fit the {self.box_height} m box once poured (needs {FILL_HEIGHT_FACTOR} x its height)"
            )
        if self.L_i < 4 * self.diameter:
            raise CaseError(f"L_i = {self.L_i} m is under 4 grain diameters ({self.diameter:.3g} m)")

    # -- resolved wall contact parameters (a wall value left None follows the grain value) -----
    @property
    def resolved_friction_wall(self) -> float:
        """friction_wall, or friction where it is None."""
        return self.friction if self.friction_wall is None else self.friction_wall

    @property
    def resolved_friction_base(self) -> float:
        """Friction of the floor (basal friction): friction_base, or the wall friction where it is None."""
        return self.resolved_friction_wall if self.friction_base is None else self.friction_base

    @property
    def resolved_restitution_wall(self) -> float:
        """restitution_wall, or restitution where it is None."""
        return self.restitution if self.restitution_wall is None else self.restitution_wall

    # -- derived geometry and scales ---------------------------------------------------------
    @property
    def H_i(self) -> float:
        """H_i = a L_i (m)."""
        return self.aspect_ratio * self.L_i

    @property
    def t_star(self) -> float:
        """Free-fall time scale sqrt(H_i / g) (s)."""
        return math.sqrt(self.H_i / GRAVITY)

    @property
    def diameter(self) -> float:
        """Mean simulated grain diameter (m), after coarse-graining."""
        return self.material.diameter * self.size_scale

    @property
    def grains_across(self) -> float:
        """Mean simulated grains across the column, L_i / diameter (the size guard's measure, see
        check_grains_across)."""
        return grains_across(self.L_i, self.material, self.size_scale)

    @property
    def density(self) -> float:
        return self.material.density

    @property
    def min_diameter(self) -> float:
        return self.diameter * (1.0 - self.polydispersity)

    def sphere_mass(self, diameter: float) -> float:
        """Mass (kg) of a sphere of `diameter`: 2D discs carry sphere mass and inertia."""
        return sphere_mass(self.density, diameter)

    @property
    def contact_time(self) -> float:
        """Undamped particle-particle contact duration of the lightest pair, pi sqrt(m_eff / kn) (s)."""
        m_eff = 0.5 * self.sphere_mass(self.min_diameter)
        return math.pi * math.sqrt(m_eff / self.normal_stiffness)

    @property
    def time_step(self) -> float:
        return self.contact_time * self.dt_over_contact_time

    @property
    def frame_interval(self) -> float:
        """Physical time between output frames (s): output_interval, or t*/25 when unset.

        A dataset for the GNS sets one output_interval for all its cases, so that one GNS step is
        the same physical time everywhere.
        """
        return self.output_interval if self.output_interval is not None else self.t_star / 25.0

    @property
    def n_frames(self) -> int:
        """Output frames including t = 0, covering duration_over_tstar * t*."""
        return int(math.floor(self.duration_over_tstar * self.t_star / self.frame_interval + 1e-9)) + 1

    @property
    def n_particles(self) -> int:
        """Grains in the column: solid fraction times the column volume at a depth of one diameter.

        This is how a 2D MFIX DEM deck (no_k, domain depth one diameter) fills a region at a given
        solids volume fraction; the settled 2D packing then sets the actual column height.
        """
        volume = self.L_i * self.H_i * self.diameter
        return max(1, int(round(self.material.solid_fraction * volume / (math.pi * self.diameter**3 / 6.0))))

    # -- serialisation ------------------------------------------------------------------------
    def physical_parameters(self) -> dict:
        """Flat dict of every physical parameter (for HDF5 attributes, decks and logs)."""
        out = {k: v for k, v in dataclasses.asdict(self).items() if k != "material"}
        out.update(
            material=self.material.name,
            material_diameter=self.material.diameter,
            material_density=self.material.density,
            material_solid_fraction=self.material.solid_fraction,
            L_i=self.L_i,
            H_i=self.H_i,
            t_star=self.t_star,
            diameter=self.diameter,
            time_step=self.time_step,
            friction_wall=self.resolved_friction_wall,
            restitution_wall=self.resolved_restitution_wall,
            friction_base=self.resolved_friction_base,
            output_interval=self.frame_interval,
        )
        return out

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        out["material"] = dataclasses.asdict(self.material)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> CollapseCase:
        """Build from a mapping; an unknown or renamed key is an error naming it (dem.fields)."""
        return from_mapping(cls, data, CaseError, "case", RENAMED_CASE_KEYS)

    def replace(self, **changes: Any) -> CollapseCase:
        return dataclasses.replace(self, **changes)


def grains_across(L_i: float, material: str | dict | Material, size_scale: float) -> float:
    """Mean grains across a column of length `L_i` (m): L_i / (material diameter x size_scale)."""
    return L_i / (get_material(material).diameter * size_scale)


def check_grains_across(
    L_i: float, material: str | dict | Material, size_scale: float, minimum: float, where: str
) -> None:
    """The size guard: refuse a column fewer than `minimum` coarse-grained grains across.

    Coarse graining (size_scale) keeps the column's L_i and a and swells the grains, so a short
    column at a large size_scale is only a few grains across, and then it collapses differently:
    the runout falls well below the fine-grained column's (config key dem.min_grains_across,
    docs/experiments/grain-size.md, "The size guard"). The one check of every DEM column the
    pipeline builds from its config (the datasets' cases, the DoE's and the diagnosis' runs;
    pipeline.config). Raises CaseError whose message starts with `where` (the config key) and
    names the grains across, the minimum, the largest size_scale that passes and the shortest L_i
    that passes at this size_scale.
    """
    material = get_material(material)
    across = grains_across(L_i, material, size_scale)
    if across >= minimum * (1 - 1e-9):  # the boundary passes: L_i = minimum x d x size_scale exactly
        return
    largest = math.floor(L_i / (minimum * material.diameter) * 100) / 100  # rounded down, so it passes
    finer = "" if largest >= 1 else " (finer than the real grains: this column is too short at any size_scale)"
    shortest = minimum * material.diameter * size_scale
    digit = 10.0 ** (math.floor(math.log10(shortest)) - 2)
    shortest = math.ceil(shortest / digit - 1e-6) * digit  # 3 significant digits, rounded up, so it passes
    raise CaseError(
        f"{where}: L_i = {L_i:g} m at size_scale {size_scale:g} is {across:.3g} {material.name} grains across "
        f"(d = {material.diameter * 1e6:.0f} um x {size_scale:g}), under the minimum of {minimum:g} "
        "(dem.min_grains_across): a column this few grains across collapses differently, its runout falls "
        f"below the fine-grained column's. Largest size_scale that passes: {largest:g}{finer}; or "
        f"L_i >= {shortest:.3g} m at size_scale {size_scale:g}"
    )


MAX_DT_OVER_CONTACT_TIME = 0.1
# Old spellings of case fields (one name per quantity): old -> new.
RENAMED_CASE_KEYS = {
    "column_length": "L_i",
    "initial_height": "H_i (derived: aspect_ratio x L_i)",
    "wall_friction": "friction_wall",
    "wall_restitution": "restitution_wall",
    "base_friction": "friction_base",
}
FILL_HEIGHT_FACTOR = 1.6  # the column is poured from up to this multiple of H_i before settling


def _check_finite(key, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CaseError(f"{key} must be a finite number, got {value!r}")
