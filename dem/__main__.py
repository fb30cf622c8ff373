"""Run one collapse case end to end with the builtin engine: trajectory HDF5 + figure.

    python -m dem --material quartz --L-i 0.02 --aspect-ratio 2 --friction 0.5 \
        --restitution 0.65 --size-scale 3 --out results/one_case/case.h5

Export any trajectory HDF5 (a DEM run of any engine, or a GNS rollout) to a ParaView time series
(dem/vtk.py: OUTDIR/<name>.pvd and one .vtu per frame):

    python -m dem export-vtk results/one_case/case.h5 results/one_case/vtk
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from dem.case import CaseError, CollapseCase
from dem.collapse import simulate_collapse
from dem.plots import plot_case
from dem.progress import progress_logger
from dem.runout import METHODS, RunoutMethod
from dem.trajectory import TrajectoryError, write_trajectory
from dem.vtk import ExportError, export_file

log = logging.getLogger("dem")


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["export-vtk"]:
        return export_vtk(argv[1:])
    parser = argparse.ArgumentParser(
        prog="python -m dem",
        description=__doc__.splitlines()[0],
        epilog="python -m dem export-vtk TRAJECTORY.h5 OUTDIR: a trajectory as a ParaView time series (--help there)",
    )
    parser.add_argument("--material", default="quartz")
    parser.add_argument("--L-i", type=float, default=0.02, help="initial column length L_i (m)")
    parser.add_argument("--aspect-ratio", type=float, default=2.0, help="a = H_i / L_i")
    parser.add_argument("--friction", type=float, default=0.5)
    parser.add_argument("--restitution", type=float, default=0.65)
    parser.add_argument("--size-scale", type=float, default=3.0, help="coarse-graining factor on the diameter")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--runout",
        choices=METHODS,
        default=RunoutMethod().method,
        help="how L* is read off the run (dem.runout; default parameters)",
    )
    parser.add_argument("--out", type=Path, default=Path("results/one_case/case.h5"))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    try:
        case = CollapseCase(
            args.material,
            args.L_i,
            args.aspect_ratio,
            args.friction,
            args.restitution,
            seed=args.seed,
            size_scale=args.size_scale,
            name=args.out.stem,
        )
    except CaseError as exc:
        parser.error(str(exc))
    log.info("case %s: %d grains, dt = %.3g s, t* = %.3g s", case.name, case.n_particles, case.time_step, case.t_star)
    traj = simulate_collapse(case, progress=progress_logger(f"case {case.name}", log))
    write_trajectory(args.out, traj)
    runout_method = RunoutMethod(args.runout)
    plot_case(traj, args.out.with_suffix(".png"), runout_method)
    t, runout = runout_method.curve(traj)
    log.info(
        "wrote %s and %s; final L* = %.3f at t/t* = %.2f", args.out, args.out.with_suffix(".png"), runout[-1], t[-1]
    )
    return 0


def export_vtk(argv: Sequence[str]) -> int:
    """`python -m dem export-vtk TRAJECTORY.h5 OUTDIR`: the trajectory as OUTDIR/<name>.pvd + one .vtu per frame."""
    parser = argparse.ArgumentParser(
        prog="python -m dem export-vtk",
        description="Export a trajectory HDF5 (a DEM run of any engine, or a GNS rollout) to a ParaView time series: "
        "one .vtu point file per frame (radius, velocity, particle_type) and a .pvd collection with the times.",
    )
    parser.add_argument("trajectory", type=Path, help="trajectory HDF5 (dem/trajectory.py)")
    parser.add_argument(
        "outdir", type=Path, help="folder to write (new, empty, or a previous export, which is replaced)"
    )
    parser.add_argument("--name", help="file names <name>.pvd, <name>_<frame>.vtu (default: the HDF5 file's stem)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    try:
        export = export_file(
            args.trajectory, args.outdir, args.name, progress_logger(f"export {args.trajectory.name}", log)
        )
    except (TrajectoryError, ExportError) as exc:
        parser.error(str(exc))
    log.info(
        "wrote %d frames (t = 0 ... %.4g s) to %s; open it in ParaView",
        len(export.frames),
        export.times[-1],
        export.pvd,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
