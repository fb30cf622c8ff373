"""MFIX (MFiX-DEM 23.x) as a DEM engine: deck from mfix_templates/, particle VTK (.vtp) output read back.

MFIX is not installable here (conda-only, registration required), so the run path is untested
here; the deck renderer is checked against golden files and the .vtp reader on real .vtp files
written by LIGGGHTS (`dump custom/vtk`). See mfix_templates/README.md.

Physics as the builtin engine: 2D (NO_K, depth one mean diameter), linear spring-dashpot (LSD)
with kn, kt = KT_FAC kn, tangential damping DES_ETAT_FAC x normal, damping from DES_EN_INPUT,
Coulomb friction MEW; MFIX computes the damping per solids-phase pair from the phases' D_P0 and
RO_S0, so polydisperse grains are split into size-class phases (at most MAX_PHASES, MFIX's default
DIM_M) as in the LIGGGHTS deck; the worst error in e that leaves is written in the deck header.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path
from string import Template

import numpy as np

from dem.case import GRAVITY, CollapseCase, sphere_mass
from dem.engines.base import EngineError, SolverEngine, read_error, refuse_unsupported, size_classes
from dem.trajectory import Trajectory

TEMPLATE = Path(__file__).resolve().parents[2] / "mfix_templates" / "collapse_2d.mfx"
DECK = "collapse.mfx"
PARTICLES = "particle_input.dat"
VTK_FILEBASE = "PARTICLES"
LOG = "mfix.log"
MAX_PHASES = 10  # MFIX's default DIM_M
RESTITUTION_TOLERANCE = 0.005
GRID_CELL_DIAMETERS = 4.0  # fluid-grid cell size in largest grain diameters (no gas is solved)


class MfixEngine(SolverEngine):
    name = "mfix"
    mechanisms = ()  # the deck is the paper's model only
    executable = "mfixsolver"
    deck_file, grains_file, log_file = DECK, PARTICLES, LOG
    frames_dir, frame_glob = ".", f"{VTK_FILEBASE}_*.vtp"
    install_hint = (
        "MFIX 23.x is distributed as a conda package after registration on NETL's MFIX site: "
        "create its conda environment (e.g. `conda create -n mfix-23.4 mfix=23.4`), and either put "
        "`mfixsolver` on PATH or set the solver path in the config (dem.solvers.mfix)."
    )

    def version(self) -> str:
        """The solver's own version line; output read where no solver is installed says so."""
        path = self.find_solver()
        if path is None:
            return "MFIX (solver not installed here; output read only)"
        try:
            out = subprocess.run([path, "--version"], capture_output=True, text=True, timeout=60)
            first = (out.stdout or out.stderr).strip().splitlines()
            return first[0] if first else "MFIX (unknown version)"
        except (OSError, subprocess.TimeoutExpired):
            return "MFIX (unknown version)"

    def render_files(self, case: CollapseCase, packing: Trajectory) -> tuple[str, str]:
        """(collapse.mfx text, particle_input.dat text): render_deck."""
        return render_deck(case, packing)

    def command(self, solver: str, deck: Path) -> list[str]:
        """mfixsolver on the .mfx deck."""
        return [solver, "-f", deck.name]

    def read(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Trajectory:
        """The particle .vtp frames in work_dir as a Trajectory."""
        positions, radius = read_vtp_frames(
            sorted(Path(work_dir).glob(self.frame_glob)), case.n_frames, case.n_particles
        )
        if not np.allclose(radius, packing.radius, rtol=1e-5):
            raise read_error(work_dir, "grain diameters in the .vtp files differ from the packing's")
        return self.grain_trajectory(
            case, positions, radius, settled_height=packing.attrs.get("settled_height", np.nan)
        )


# -- deck -----------------------------------------------------------------------------------------
def _real(value) -> str:
    """A Fortran-readable real: shortest text that reads back as the same float64."""
    return repr(float(value))


def phases(case: CollapseCase, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Phase (1..M) per grain for radii [N] (m), phase diameters [M] (m) and worst relative error of e."""
    mass = sphere_mass(case.density, 2 * np.asarray(radius, float))
    index, class_mass, worst = size_classes(
        mass, (case.restitution, case.resolved_restitution_wall), RESTITUTION_TOLERANCE, MAX_PHASES
    )
    diameter = np.array([math.cbrt(6 * m / (math.pi * case.density)) for m in class_mass.tolist()])  # as size_classes
    return index + 1, diameter, worst


def render_deck(case: CollapseCase, packing: Trajectory) -> tuple[str, str]:
    """(collapse.mfx text, particle_input.dat text) for `case` from the last frame of `packing`."""
    refuse_unsupported(case, "mfix", MfixEngine.mechanisms)
    positions = np.asarray(packing.positions[-1], float)
    radius = np.asarray(packing.radius, float)
    phase, phase_diameter, worst = phases(case, radius)
    n_phases = len(phase_diameter)
    solids = "".join(
        f"  {f'SOLIDS_MODEL({m})':<19}= 'DEM'\n  {f'D_P0({m})':<19}= {_real(d)}\n"
        f"  {f'RO_S0({m})':<19}= {_real(case.density)}\n"
        for m, d in enumerate(phase_diameter, start=1)
    )
    n_pairs = n_phases * (n_phases + 1) // 2  # upper triangle 11 12 .. 1M 22 .. MM
    cell = GRID_CELL_DIAMETERS * 2 * float(radius.max())
    values = dict(
        case_name=case.name or "?",
        run_name=re.sub(r"[^A-Za-z0-9_]", "_", case.name or "COLLAPSE")[:60],
        n_particles=len(radius),
        n_phases=n_phases,
        restitution_error=f"{worst:.2%}",
        n_frames=case.n_frames,
        L_i=_real(case.L_i),
        aspect_ratio=_real(case.aspect_ratio),
        duration=_real((case.n_frames - 1) * case.frame_interval),
        frame_interval=_real(case.frame_interval),
        gravity=_real(GRAVITY),
        box_width=_real(case.box_width),
        box_height=_real(case.box_height),
        depth=_real(case.diameter),
        imax=max(1, int(case.box_width / cell)),
        jmax=max(1, int(case.box_height / cell)),
        solids_phases=solids,
        kn=_real(case.normal_stiffness),
        kt_fac=_real(case.tangential_stiffness_ratio),
        etat_fac=_real(case.tangential_damping_ratio),
        en_input=" ".join([_real(case.restitution)] * n_pairs),
        en_wall_input=" ".join([_real(case.resolved_restitution_wall)] * n_phases),
        mew=_real(case.friction),
        mew_w=_real(case.resolved_friction_wall),
        dtsolid_factor=_real(1.0 / case.dt_over_contact_time),
        vtk_filebase=VTK_FILEBASE,
    )
    deck = Template(TEMPLATE.read_text()).substitute(values)
    lines = [
        "! MFiX particle input file, version 2.0, written by dem/engines/mfix.py",
        f"! settled packing of case {case.name or '?'}: {len(radius)} grains in 2D",
        "!",
        "Version = 2.0",
        "Dimension = 2",
        f"Particles = {len(radius)}",
        "!",
        "! Variable     Read  Default",
        "Phase_ID       T     1",
        "Diameter       T     0.0",
        "Density        T     0.0",
        "Velocity       T     0.0 0.0",
        "Temperature    F     293.15",
        "Species        F     1.0",
        "User_scalar    F     0.0",
        "!",
        "! x y phase_id diameter density u v",
    ]
    lines += [
        f"{_real(x)} {_real(y)} {m} {_real(2 * r)} {_real(case.density)} 0.0 0.0"
        for (x, y), r, m in zip(positions, radius, phase)
    ]
    return deck, "\n".join(lines) + "\n"


# -- .vtp particle files --------------------------------------------------------------------------
def read_vtp(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Points [N, 3] (m) and point data {name: array} of a VTK XML PolyData (.vtp) file.

    The data arrays are decoded by meshio's VTK XML machinery (ascii, base64 binary, raw appended,
    zlib/lzma compressed), which meshio itself only exposes for .vtu files. A file that is not
    VTK PolyData, or is truncated, raises EngineError naming it.
    """
    from meshio.vtu._vtu import VtuReader, _parse_raw_binary

    path = Path(path)
    try:
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as exc:
            if b"<AppendedData" not in path.read_bytes():
                raise read_error(path, f"not a complete XML file ({exc}); truncated or not VTK") from None
            root = _parse_raw_binary(str(path))  # raw appended binary, as MFIX writes
        if root.tag != "VTKFile" or root.get("type") != "PolyData":
            raise read_error(path, f"not a VTK PolyData (.vtp) file (root <{root.tag} type={root.get('type')!r}>)")
        decoder = VtuReader.__new__(VtuReader)
        decoder.compression = root.get("compressor")
        decoder.header_type = root.get("header_type", "UInt32")
        decoder.byte_order = root.get("byte_order")
        appended = root.find("AppendedData")
        decoder.appended_data = appended.text.strip()[1:] if appended is not None else None
        pieces = root.findall("PolyData/Piece")
        if len(pieces) != 1:
            raise read_error(path, f"expected one Piece, found {len(pieces)}")
        piece = pieces[0]
        n = int(piece.get("NumberOfPoints"))
        points_array = piece.find("Points/DataArray")
        if points_array is None:
            raise read_error(path, "no Points")
        points = decoder.read_data(points_array)
        if points.size != 3 * n:
            raise read_error(path, f"Points hold {points.size} values, expected 3 x {n}")
        data = {}
        for array in piece.findall("PointData/DataArray"):
            values = decoder.read_data(array)
            if len(values) != n:
                raise read_error(path, f"point data {array.get('Name')!r} has {len(values)} entries, expected {n}")
            data[array.get("Name")] = values
        return points.reshape(n, 3).astype(np.float64), data
    except EngineError:
        raise
    except Exception as exc:  # meshio ReadError, base64/zlib errors, bad attributes: all mean a bad file
        raise read_error(
            path, f"unreadable VTK data ({type(exc).__name__}: {exc}); truncated or not a .vtp particle file"
        ) from None


def _frame_number(path: Path) -> int:
    match = re.search(r"(\d+)\.vtp$", path.name)
    if match is None:
        raise read_error(path, "no frame number in the file name")
    return int(match.group(1))


def _radius_of(path, data: dict) -> np.ndarray:
    lower = {name.lower(): name for name in data}
    if "radius" in lower:
        return np.asarray(data[lower["radius"]], float).ravel()
    if "diameter" in lower:
        return 0.5 * np.asarray(data[lower["diameter"]], float).ravel()
    raise read_error(path, f"no Diameter or radius point data (found {sorted(data)})")


def _ids_of(data: dict):
    for name in data:
        if name.lower() in ("id", "particle_id", "global_id"):
            return np.asarray(data[name]).ravel()
    return None


def read_vtp_frames(files: Iterable[Path], n_frames: int, n_particles: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions [n_frames, N, 2] float32 (m) and radius [N] (m) from particle .vtp files, one per
    frame, ordered by the number in their names. Grains are ordered by their id array when the
    files carry one (LIGGGHTS 'id'; MFIX 'Particle_ID' where written), else kept in file order,
    which is checked through their diameters."""
    files = sorted(files, key=_frame_number)
    if len(files) != n_frames:
        where = files[0].parent if files else "output folder"
        raise read_error(where, f"expected {n_frames} particle .vtp frames, found {len(files)}")
    positions = np.empty((n_frames, n_particles, 2), np.float32)
    radius = None
    for k, path in enumerate(files):
        points, data = read_vtp(path)
        if len(points) != n_particles:
            raise read_error(path, f"{len(points)} particles, the case has {n_particles}")
        frame_radius = _radius_of(path, data)
        ids = _ids_of(data)
        if ids is not None:
            order = np.argsort(ids, kind="stable")
            points, frame_radius = points[order], frame_radius[order]
        if radius is None:
            radius = frame_radius
        elif not np.allclose(frame_radius, radius, rtol=1e-5):
            raise read_error(path, "particle sizes changed between frames (order or count not kept)")
        if not np.all(np.isfinite(points[:, :2])):
            raise read_error(path, "non-finite positions")
        positions[k] = points[:, :2]
    return positions, radius
