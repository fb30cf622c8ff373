"""THE calibration objective, shared by the DoE, the GNS inverse design and the diagnosis.

objective = mean over the measured t/t* points of (L*_simulated - L*_measured)^2, the MSE of the
runout curve that Jiang et al. (2024, section 2.3) minimise. The simulated curve comes from a
trajectory (DEM run or GNS rollout, through dem.runout.runout_at) or from arrays.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from calibration.measured_column import MeasuredColumn
from dem.runout import RunoutMethod, runout_at

if TYPE_CHECKING:
    import torch

    from dem.trajectory import Trajectory

GEOMETRY_RTOL = 1e-6


class ObjectiveError(ValueError):
    """Simulation and measurement cannot be compared; the message says why."""


def runout_mse(
    simulated_runout: np.ndarray | torch.Tensor, measured_runout: np.ndarray | torch.Tensor
) -> float | torch.Tensor:
    """MSE between simulated and measured L*, both [K] at the same t/t* points.

    Written with array operators only, so it works unchanged on torch tensors (autograd) as well
    as on numpy arrays; returns a float for numpy input.
    """
    if len(simulated_runout) != len(measured_runout):
        raise ObjectiveError(f"simulated runout has {len(simulated_runout)} points, measured {len(measured_runout)}")
    squared = (simulated_runout - measured_runout) ** 2
    mse = squared.mean()
    return float(mse) if isinstance(mse, (np.ndarray, np.generic, float)) else mse


def simulated_runout_at(t_over_tstar: np.ndarray, runout: np.ndarray, measured: MeasuredColumn) -> np.ndarray:
    """[K] simulated L* interpolated (linearly) at the measured t/t* points.

    t_over_tstar [T] increasing, runout [T]: a simulated curve. Measured points outside
    [t_over_tstar[0], t_over_tstar[-1]] are an error: extrapolating a runout is not a measurement.
    """
    t = np.asarray(t_over_tstar, float)
    runout = np.asarray(runout, float)
    if t.ndim != 1 or t.shape != runout.shape or len(t) < 2:
        raise ObjectiveError(
            f"simulated curve: t/t* {t.shape} and L* {runout.shape} must be equal 1-D arrays of at least 2 points"
        )
    if np.any(np.diff(t) <= 0):
        raise ObjectiveError("simulated curve: t/t* must increase")
    check_window(t[0], t[-1], measured)
    return np.interp(measured.t_over_tstar, t, runout)


def check_window(t_first: float, t_last: float, measured: MeasuredColumn) -> None:
    """Every measured t/t* must lie in the simulated window [t_first, t_last]."""
    times = measured.t_over_tstar
    outside = times[(times < t_first - 1e-9) | (times > t_last + 1e-9)]
    if outside.size:
        raise ObjectiveError(
            f"measured column {measured.name!r} ({measured.source}): t/t* = {outside.tolist()} "
            f"fall outside the simulated window [{t_first:.3g}, {t_last:.3g}]; simulate longer "
            "(duration_over_tstar) or drop those points"
        )


def objective_from_curve(t_over_tstar: np.ndarray, runout: np.ndarray, measured: MeasuredColumn) -> float:
    """MSE of a simulated runout curve (t/t* [T], L* [T]) against `measured`."""
    return runout_mse(simulated_runout_at(t_over_tstar, runout, measured), measured.runout)


def check_same_column(trajectory_attrs: dict, measured: MeasuredColumn, where: str = "trajectory") -> None:
    """A simulation compared with a measurement must be of the same column: material, a and L_i.

    The grain size may differ (coarse-graining); the column geometry and material may not.
    """
    if str(trajectory_attrs.get("material")) != measured.material:
        raise ObjectiveError(
            f"{where}: material {trajectory_attrs.get('material')!r} differs from the measured "
            f"column {measured.name!r} ({measured.material})"
        )
    for key, value in (("aspect_ratio", measured.aspect_ratio), ("L_i", measured.L_i)):
        simulated = float(trajectory_attrs[key])
        if not math.isclose(simulated, value, rel_tol=GEOMETRY_RTOL):
            raise ObjectiveError(
                f"{where}: {key} = {simulated:g} differs from the measured column "
                f"{measured.name!r} ({key} = {value:g}, {measured.source})"
            )


def objective(trajectory: Trajectory, measured: MeasuredColumn, runout: RunoutMethod) -> float:
    """MSE of a trajectory's runout, read by the runout method `runout`, against `measured`.

    trajectory: a dem.trajectory.Trajectory (DEM or GNS rollout) of the measured column's geometry.
    """
    check_same_column(trajectory.attrs, measured)
    t = trajectory.t_over_tstar
    check_window(t[0], t[-1], measured)
    return runout_mse(runout_at(trajectory, measured.t_over_tstar, runout), measured.runout)
