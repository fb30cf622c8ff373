"""Runout of a collapsing column: every way of reading the front, its deposit profile, final height.

L*(t) = (L(t) - L_i) / L_i, with L (m) the front of the collapsing mass at time t. This module is
the only place in the project that computes a front; every stage reads it through one
`RunoutMethod` (the config's `runout` section, `RunoutMethod.from_config`), so two stages that
score the same run score the same number. Its differentiable twin is gns/runout.py.

Methods (every length in mean grain diameters d, so a method means the same at every size_scale):

- `connected_front`: L = mean of x + r over the `n_leading` leading grains of the deposit
  connected to the column foot (grains connected when their gap is below `gap_tolerance` d).
  Grains rolling alone ahead of the deposit do not count, but a sparse chain still does.
- `dense_front`: L = x + r of the farthest grain that has at least `n_neighbours` other grain
  centres within `neighbour_radius` d of its own centre (Jiang et al.'s public code: 8 centres
  within 1 mm, ~2.4 quartz diameters). A single layer of grains on the floor has 4 such
  neighbours, a two-layer sheet 8: only the dense body of the flow counts, as on a lab image.
- `*_reached` (`connected_front_reached`, `dense_front_reached`): the farthest that front has
  reached up to t (running maximum). A measured runout read off images never moves back; the
  instantaneous front does when leading grains detach or a chain breaks.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from dem.fields import from_mapping

if TYPE_CHECKING:
    from dem.trajectory import Trajectory

FRONTS = ("connected_front", "dense_front")
REACHED = "_reached"
METHODS = FRONTS + tuple(f + REACHED for f in FRONTS)


class RunoutError(ValueError):
    """A runout method is badly set, or a frame has no front by its rule; the message says where."""


@dataclass(frozen=True)
class RunoutMethod:
    """How a front is read off grain positions; the config's `runout` section.

    method: one of METHODS. n_leading (grains) and gap_tolerance (d) serve the connected front;
    n_neighbours (grain centres) and neighbour_radius (d, centre to centre) the dense front.
    """

    method: str = "dense_front_reached"
    n_leading: int = 8
    gap_tolerance: float = 2.0
    n_neighbours: int = 8
    neighbour_radius: float = 2.4

    def __post_init__(self):
        problems = []
        if self.method not in METHODS:
            problems.append(f"runout.method: {self.method!r} is not a method (choose one of {list(METHODS)})")
        for key in ("n_leading", "n_neighbours"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                problems.append(f"runout.{key}: {value!r} must be a whole number of grains, at least 1")
        for key in ("gap_tolerance", "neighbour_radius"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
                problems.append(f"runout.{key}: {value!r} must be a positive number of mean grain diameters")
        if problems:
            raise RunoutError("; ".join(problems))

    @classmethod
    def from_config(cls, section: dict | RunoutMethod | str | None) -> RunoutMethod:
        """From the config's `runout` section (a dict), a method name, or an instance; None: the default."""
        if isinstance(section, RunoutMethod):
            return section
        if section is None:
            return cls()
        if isinstance(section, str):
            return cls(method=section)
        return from_mapping(cls, section, RunoutError, "runout")

    def to_config(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def front_rule(self) -> str:
        """The instantaneous rule: 'connected_front' or 'dense_front'."""
        return self.method.removesuffix(REACHED)

    @property
    def reached(self) -> bool:
        """True: the running maximum of the front ("farthest front reached")."""
        return self.method.endswith(REACHED)

    @property
    def label(self) -> str:
        """One line for reports and figure legends."""
        if self.front_rule == "connected_front":
            rule = f"connected front (mean of {self.n_leading} leading grains, gaps < {self.gap_tolerance:g} d)"
        else:
            rule = (
                f"dense front (farthest grain with >= {self.n_neighbours} centres within {self.neighbour_radius:g} d)"
            )
        return rule + (", farthest reached" if self.reached else ", instantaneous")

    # -- one frame --------------------------------------------------------------------------------
    def front_mask(self, positions: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """[N] bool: the grains that may hold the front under this rule (positions [N, 2], radius [N], m)."""
        if self.front_rule == "connected_front":
            return deposit_mask(positions, radius, self.gap_tolerance)
        return dense_mask(positions, radius, self.n_neighbours, self.neighbour_radius)

    def front_position(self, positions: np.ndarray, radius: np.ndarray, where: str = "frame") -> float:
        """L (m) of one frame (positions [N, 2], radius [N], m) by the instantaneous rule; RunoutError
        (naming `where`) when no grain qualifies."""
        radius = np.asarray(radius, np.float64)
        mask = self.front_mask(positions, radius)
        if not mask.any():
            rule = (
                f"no grain has {self.n_neighbours} grain centres within {self.neighbour_radius:g} mean diameters"
                if self.front_rule == "dense_front"
                else "no grain is connected to the column foot"
            )
            raise RunoutError(
                f"{where}: {rule}, so the {self.front_rule} rule finds no front; the grains are "
                "too sparse for this runout method"
            )
        front = np.asarray(positions, np.float64)[mask, 0] + radius[mask]
        if self.front_rule == "dense_front":
            return float(front.max())
        k = min(self.n_leading, front.size)
        return float(np.mean(np.partition(front, front.size - k)[-k:]))

    # -- a trajectory -----------------------------------------------------------------------------
    def curve(self, trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray]:
        """(t/t* [T], L* [T]) of a dem.trajectory.Trajectory (DEM run or GNS rollout)."""
        L_i = float(trajectory.attrs["L_i"])
        source = getattr(trajectory, "source", "") or "trajectory"
        front = np.array(
            [
                self.front_position(frame, trajectory.radius, where=f"{source}, frame {k}")
                for k, frame in enumerate(trajectory.positions)
            ]
        )
        if self.reached:
            front = np.maximum.accumulate(front)
        return trajectory.t_over_tstar, (front - L_i) / L_i

    def at(self, trajectory: Trajectory, t_over_tstar: ArrayLike) -> np.ndarray:
        """L* [K] interpolated at t/t* points [K]; points outside the simulated window are an error."""
        t, runout = self.curve(trajectory)
        t_query = np.asarray(t_over_tstar, float)
        if t_query.min() < t[0] - 1e-9 or t_query.max() > t[-1] + 1e-9:
            raise ValueError(
                f"t/t* points {t_query.tolist()} fall outside the simulated window [{t[0]:.3g}, {t[-1]:.3g}]"
            )
        return np.interp(t_query, t, runout)


def runout_curve(trajectory: Trajectory, method: RunoutMethod | dict | str) -> tuple[np.ndarray, np.ndarray]:
    """(t/t* [T], L* [T]) of a trajectory by the named runout method (RunoutMethod, config dict or name)."""
    return RunoutMethod.from_config(method).curve(trajectory)


def runout_at(trajectory: Trajectory, t_over_tstar: ArrayLike, method: RunoutMethod | dict | str) -> np.ndarray:
    """L* [K] at t/t* points [K] by the named runout method; outside the simulated window is an error."""
    return RunoutMethod.from_config(method).at(trajectory, t_over_tstar)


def check_same_method(found: dict | None, expected: RunoutMethod, where: str) -> None:
    """RunoutError when numbers read with runout method `found` (a config dict, or None when the
    file says nothing) would be mixed with ones read by `expected`."""
    if found is None:
        raise RunoutError(
            f"{where}: states no runout method (it was scored before runout methods were "
            f"recorded); rerun it with runout {expected.to_config()}"
        )
    if RunoutMethod.from_config(found) != expected:
        raise RunoutError(
            f"{where}: scored with runout {dict(found)}, not the configured {expected.to_config()}; "
            "rerun it (scores read two ways are never mixed)"
        )


# -- the grain sets a front is read from -----------------------------------------------------------
def deposit_mask(positions: np.ndarray, radius: np.ndarray, gap_tolerance: float = 2.0) -> np.ndarray:
    """[N] bool: grains connected to the column foot (gaps below gap_tolerance mean diameters).

    positions [N, 2] (m), radius [N] (m). The foot is the grain nearest the origin (the bottom of
    the column against the left wall).
    """
    positions = np.asarray(positions, np.float64)
    radius = np.asarray(radius, np.float64)
    diameter = 2.0 * float(np.mean(radius))
    reach = 2.0 * float(np.max(radius)) + gap_tolerance * diameter
    pairs = cKDTree(positions).query_pairs(reach, output_type="ndarray")
    if len(pairs):
        gap = (
            np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
            - radius[pairs[:, 0]]
            - radius[pairs[:, 1]]
        )
        pairs = pairs[gap <= gap_tolerance * diameter]
    n = len(positions)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    foot = int(np.argmin(np.hypot(positions[:, 0], positions[:, 1])))
    return label == label[foot]


def dense_mask(
    positions: np.ndarray, radius: np.ndarray, n_neighbours: int = 8, neighbour_radius: float = 2.4
) -> np.ndarray:
    """[N] bool: grains with at least n_neighbours other grain centres within neighbour_radius mean
    diameters of their own centre. positions [N, 2] (m), radius [N] (m)."""
    positions = np.asarray(positions, np.float64)
    reach = neighbour_radius * 2.0 * float(np.mean(radius))
    # each pair within reach once, counted for both grains: the same counts as a ball query per
    # grain (itself excluded), in under half its time on a collapse's frames
    pairs = cKDTree(positions).query_pairs(reach, output_type="ndarray")
    return np.bincount(pairs.ravel(), minlength=len(positions)) >= n_neighbours


# -- the deposit ----------------------------------------------------------------------------------
def deposit_profile(
    positions: np.ndarray, radius: np.ndarray, bin_width: float | None = None, gap_tolerance: float = 2.0
) -> tuple[np.ndarray, np.ndarray]:
    """Height profile of the connected deposit: (x bin centres [B] m, height [B] m).

    positions [N, 2] (m), radius [N] (m). height is the top (y + r) of the highest deposit grain in
    each bin; empty bins give 0. bin_width (m) defaults to two mean diameters.
    """
    positions = np.asarray(positions, np.float64)
    mask = deposit_mask(positions, radius, gap_tolerance)
    bin_width = bin_width or 4.0 * float(np.mean(radius))
    x, top = positions[mask, 0], positions[mask, 1] + radius[mask]
    edges = np.arange(0.0, x.max() + radius.max() + bin_width, bin_width)
    index = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
    height = np.zeros(len(edges) - 1)
    np.maximum.at(height, index, top)
    return 0.5 * (edges[:-1] + edges[1:]), height


def profile_at(trajectory: Trajectory, t_over_tstar: float, x: ArrayLike, bin_width: float) -> np.ndarray:
    """Height [P] (m) of the grains at x [P] (m), read as a deposit profile is read off an image:
    the highest point of grain in the strip of width `bin_width` (m) centred on each x, in the frame
    nearest t/t*; 0 where no grain reaches into the strip. A grain whose centre lies in the strip
    shows its top (y + r); one beside it, the height of its rim at the strip's nearer edge. (Counting
    centres only would leave a strip narrower than a grain empty, or read a lower grain, at random:
    a coarse-grained model read in the bins of finer measured grains would then be mostly noise.)

    Every stage that compares a simulated profile with a measured one reads it here, at the time and
    with the bin width the measurement states (calibration.measured), so that the binning and the
    reading time are never part of a misfit. A t/t* outside the simulated window (by more than half
    a frame) or a bin width that is not positive is an error.
    """
    if not bin_width > 0:
        raise RunoutError(f"{trajectory.source or 'trajectory'}: profile bin width must be positive, got {bin_width}")
    times = trajectory.t_over_tstar
    half_frame = 0.5 * (times[-1] - times[0]) / max(len(times) - 1, 1)
    if not times[0] - half_frame <= t_over_tstar <= times[-1] + half_frame:
        raise RunoutError(
            f"{trajectory.source or 'trajectory'}: a profile read at t/t* = {t_over_tstar:g} lies outside the "
            f"simulated window [{times[0]:.3g}, {times[-1]:.3g}]; simulate longer or read it earlier"
        )
    frame = int(np.argmin(np.abs(times - t_over_tstar)))
    position = np.asarray(trajectory.positions[frame], np.float64)
    radius = np.asarray(trajectory.radius, np.float64)
    x = np.asarray(x, np.float64)
    # horizontal distance from each grain centre to the strip [P, N]; 0 for a centre inside it
    gap = np.maximum(np.abs(position[None, :, 0] - x[:, None]) - 0.5 * bin_width, 0.0)
    rim = np.sqrt(np.maximum(radius[None, :] ** 2 - gap**2, 0.0))
    height = np.where(gap < radius[None, :], position[None, :, 1] + rim, 0.0)
    return height.max(axis=1, initial=0.0)


def final_height(positions: np.ndarray, radius: np.ndarray, gap_tolerance: float = 2.0) -> float:
    """Highest point (m) of the connected deposit; positions [N, 2] (m), radius [N] (m)."""
    return float(deposit_profile(positions, radius, gap_tolerance=gap_tolerance)[1].max())
