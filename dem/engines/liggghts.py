"""LIGGGHTS (Debian package `liggghts`, LIGGGHTS-PUBLIC 3.8.0) as a DEM engine.

The deck reproduces the builtin physics (ARCHITECTURE.md, "Engines"):
- One layer of spheres in 3D, all at z = 0: no contact, wall or gravity force has a z component,
  so the motion stays planar exactly. `dimension 2` + `fix enforce2d` would also run, but there
  this build gives grains the disc inertia 1/2 m r^2 (a grain launched sliding ends rolling at
  2/3 of its speed instead of the sphere's 5/7; tests/test_liggghts.py checks 5/7), and turns a
  per-atom density into mass per unit depth. In 3D read_data gives the sphere mass
  rho pi d^3 / 6 and `fix nve/sphere` the sphere inertia 2/5 m r^2, as the builtin engine.
- Grains come from the settled packing (`read_data`); `fix particletemplate/sphere` is not used.
- `pair_style gran model hooke/stiffness tangential history`: Fn = kn overlap + gamman m_eff v_n,
  Ft = kt spring + gammat m_eff v_t with the spring rescaled to mu |Fn| on slip. Damping scales
  with m_eff per contact, so gamman = 2 sqrt(kn / m_eff) |ln e| / sqrt(pi^2 + ln^2 e) must be set
  per type pair. Grains are binned by mass into size classes (one atom type each,
  base.size_classes) so that e stays within RESTITUTION_TOLERANCE (0.5%) for every contact; the
  side walls and the floor are two more types (a wall contact has m_eff = m), so that the floor can
  carry its own friction (case.friction_base).
- Rolling resistance (case.rolling_friction): `rolling_friction epsd2`, as the builtin's EPSD2.
  Cohesion, channel side-wall friction and a lifting gate have no matching LIGGGHTS 3.8 model in
  this deck: such cases are refused with a clear error.
- Walls: floor y = 0, left x = 0, right x = box_width (`fix wall/gran ... primitive`); no lid. No
  gate: the collapse starts from the settled packing with the gate removed at t = 0.
- The time step divides the frame interval exactly, never above case.time_step (as the builtin).
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np

from dem.case import GRAVITY, CollapseCase, sphere_mass
from dem.engines.base import SolverEngine, damping_ratio, read_error, refuse_unsupported, size_classes
from dem.integrate import frame_steps
from dem.trajectory import Trajectory

RESTITUTION_TOLERANCE = 0.005  # worst relative error of e from size-class damping
SUPPORTED = ("rolling_friction", "friction_base")  # candidate mechanisms this deck reproduces
MAX_SIZE_CLASSES = 60
DECK = "in.collapse"
DATA = "packing.data"
FRAMES = "frames"  # one dump file per frame: frames/frame.<step>.txt
LOG = "log.liggghts"
DUMP_COLUMNS = ("id", "type", "x", "y", "radius", "mass")


class LiggghtsEngine(SolverEngine):
    name = "liggghts"
    mechanisms = SUPPORTED
    executable = "liggghts"
    deck_file, grains_file, log_file = DECK, DATA, LOG
    frames_dir, frame_glob = FRAMES, "frame.*.txt"
    install_hint = (
        "Install LIGGGHTS 3.8 (Debian/Ubuntu: `apt-get install liggghts`), or set the solver "
        "path in the config (dem.solvers.liggghts)."
    )

    def version(self) -> str:
        """'LIGGGHTS-PUBLIC 3.8.0' from the solver's help banner."""
        path = self.require_solver()
        # -log none: LIGGGHTS otherwise leaves a log.liggghts in the current folder, even for -h
        out = subprocess.run([path, "-log", "none", "-h"], capture_output=True, text=True, timeout=30).stdout
        match = re.search(r"Version\s+(LIGGGHTS[^,)\s]*\s+[\d.]+)", out)
        return match.group(1) if match else "LIGGGHTS (unknown version)"

    def render_files(self, case: CollapseCase, packing: Trajectory) -> tuple[str, str]:
        """(input script, data file) text: render_deck."""
        return render_deck(case, packing)

    def command(self, solver: str, deck: Path) -> list[str]:
        """LIGGGHTS on the input script, its own log file off (stdout is kept in LOG)."""
        return [solver, "-in", deck.name, "-log", "none", "-nocite"]

    def read(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Trajectory:
        """The dump frames in work_dir/FRAMES as a Trajectory; attrs add the time step dt (s), the
        steps run and the solver's loop time (loop_time)."""
        work_dir = Path(work_dir)
        positions, radius = self.read_frames(case, packing, work_dir)
        steps, dt = frame_steps(case.frame_interval, case.time_step)
        return self.grain_trajectory(
            case,
            positions,
            radius,
            dt=dt,
            steps=steps * (case.n_frames - 1),
            settled_height=packing.attrs.get("settled_height", np.nan),
            **loop_time(work_dir / LOG),
        )

    def read_frames(self, case: CollapseCase, packing: Trajectory, work_dir: Path) -> tuple[np.ndarray, np.ndarray]:
        """Positions [n_frames, N, 2] float32 (m) and radius [N] (m) of the dump frames in
        work_dir/FRAMES, checked against the grains of `packing` (the run's start)."""
        positions, radius = read_dump_frames(work_dir / FRAMES, case.n_frames, case.n_particles)
        if not np.allclose(radius, packing.radius, rtol=1e-6):
            raise read_error(
                work_dir / FRAMES, "grain radii differ from the packing's: these frames belong to another case"
            )
        return positions, radius


# -- deck -----------------------------------------------------------------------------------------
def grain_types(case: CollapseCase, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Atom type per grain (1..K, size classes) for radii [N] (m), class masses [K] (kg), worst
    relative error of e."""
    mass = sphere_mass(case.density, 2 * np.asarray(radius, float))
    index, class_mass, worst = size_classes(
        mass, (case.restitution, case.resolved_restitution_wall), RESTITUTION_TOLERANCE, MAX_SIZE_CLASSES
    )
    return index + 1, class_mass, worst


def pair_tables(case: CollapseCase, class_mass: np.ndarray) -> dict:
    """Per type-pair property matrices [(K+2), (K+2)] for class masses [K] (kg): types 1..K grains
    (size classes), K+1 the left and right walls, K+2 the floor; kn, kt in N/m, gamman and gammat
    in 1/s (LIGGGHTS multiplies them by m_eff), friction coefficients dimensionless."""
    k = len(class_mass)
    kn = case.normal_stiffness
    m_eff = np.full((k + 2, k + 2), class_mass.mean())  # wall-wall entries are never used
    m_eff[:k, :k] = np.outer(class_mass, class_mass) / np.add.outer(class_mass, class_mass)
    for wall in (k, k + 1):
        m_eff[:k, wall] = m_eff[wall, :k] = class_mass  # a wall contact: m_eff = m
    zeta = np.full((k + 2, k + 2), damping_ratio(case.resolved_restitution_wall))
    zeta[:k, :k] = damping_ratio(case.restitution)
    mu = np.full((k + 2, k + 2), case.resolved_friction_wall)
    mu[:k, :k] = case.friction
    mu[:, k + 1] = mu[k + 1, :] = case.resolved_friction_base
    gamman = 2.0 * np.sqrt(kn / m_eff) * zeta  # LIGGGHTS multiplies it by m_eff again
    tables = {
        "kn": np.full((k + 2, k + 2), kn),
        "kt": np.full((k + 2, k + 2), case.tangential_stiffness_ratio * kn),
        "gamman": gamman,
        "gammat": case.tangential_damping_ratio * gamman,
        "coefficientFriction": mu,
    }
    if case.rolling_friction > 0:
        tables["coefficientRollingFriction"] = np.full((k + 2, k + 2), case.rolling_friction)
    return tables


def _num(value) -> str:
    """Shortest text that reads back as the same float64."""
    return repr(float(value))


def _matrix_lines(name: str, matrix) -> str:
    n = matrix.shape[0]
    rows = [" ".join(f"{v:.10g}" for v in row) for row in matrix]
    body = " &\n    ".join(rows)
    return f"fix {name} all property/global {name} peratomtypepair {n} &\n    {body}"


def render_deck(case: CollapseCase, packing: Trajectory, vtk: bool = False) -> tuple[str, str]:
    """(input script, data file) text for `case` starting from the last frame of `packing`.

    vtk: also write every frame as VTK PolyData, frames/particles_<step>.vtp (ascii), e.g. for
    ParaView or to test .vtp readers on real solver output."""
    refuse_unsupported(case, "liggghts", SUPPORTED)
    positions = np.asarray(packing.positions[-1], float)
    radius = np.asarray(packing.radius, float)
    types, class_mass, worst = grain_types(case, radius)
    n_types = len(class_mass) + 2
    side_wall_type, floor_type = n_types - 1, n_types
    steps_per_frame, dt = frame_steps(case.frame_interval, case.time_step)
    n_steps = steps_per_frame * (case.n_frames - 1)
    skin = 0.4 * float(radius.mean())  # as the builtin's pair-list skin
    depth = 2 * float(radius.max())
    data = [
        f"LIGGGHTS data: settled packing of case {case.name or '?'} ({len(radius)} grains)",
        "",
        f"{len(radius)} atoms",
        f"{n_types} atom types",
        "",
        f"0 {_num(case.box_width)} xlo xhi",
        f"0 {_num(case.box_height)} ylo yhi",
        f"{_num(-depth / 2)} {_num(depth / 2)} zlo zhi",
        "",
        "Atoms",
        "",
    ]
    # columns: id type diameter density x y z; in 3D the mass is the sphere's, rho pi d^3 / 6
    for i, ((x, y), r, t) in enumerate(zip(positions, radius, types), start=1):
        data.append(f"{i} {t} {_num(2 * r)} {_num(case.density)} {_num(x)} {_num(y)} 0")
    tables = pair_tables(case, class_mass)
    # keyword order: tangential, cohesion, rolling_friction
    model = "model hooke/stiffness tangential history" + (
        " rolling_friction epsd2" if case.rolling_friction > 0 else ""
    )
    wall = f"all wall/gran {model} primitive type"
    vtk_dump = (
        (
            f"dump            particles all custom/vtk {steps_per_frame} {FRAMES}/particles_*.vtp "
            "id type x y z radius mass vx vy\n"
        )
        if vtk
        else ""
    )
    properties = "\n".join(_matrix_lines(name, table) for name, table in tables.items())
    deck = f"""# LIGGGHTS 3.8 input: 2D granular column collapse, rendered by dem/engines/liggghts.py
# case: {case.name or "?"}; {len(radius)} grains from the settled packing ({DATA}); gate removed at t = 0
# frames: {case.n_frames}
# grain types 1..{n_types - 2}: size classes (damping per class pair keeps e within {worst:.2%});
# type {side_wall_type}: left and right walls; type {floor_type}: floor
# One layer of spheres in 3D (all z = 0, no force ever leaves the plane): in 2D LIGGGHTS gives
# the grains disc inertia 1/2 m r^2 instead of the sphere's 2/5 m r^2.
atom_style      granular
atom_modify     map array
dimension       3
boundary        f fm f
newton          off
communicate     single vel yes
units           si
processors      * * 1

read_data       {DATA}

neighbor        {_num(skin)} bin
neigh_modify    delay 0

{properties}

pair_style      gran {model}
pair_coeff      * *

timestep        {_num(dt)}
fix gravity     all gravity {_num(GRAVITY)} vector 0.0 -1.0 0.0
fix floor       {wall} {floor_type} yplane 0.0
fix left_wall   {wall} {side_wall_type} xplane 0.0
fix right_wall  {wall} {side_wall_type} xplane {_num(case.box_width)}
fix integrate   all nve/sphere

thermo_style    custom step atoms ke cpu
thermo          {max(1, n_steps // 20)}
thermo_modify   lost error norm no

dump            frames all custom {steps_per_frame} {FRAMES}/frame.*.txt {" ".join(DUMP_COLUMNS)}
dump_modify     frames sort id format "%d %d %.9g %.9g %.9g %.9g"
{vtk_dump}run             {n_steps}
"""
    return deck, "\n".join(data) + "\n"


# -- output ---------------------------------------------------------------------------------------
def loop_time(log: str | os.PathLike) -> dict:
    """{wall_time_s, particle_steps_per_second} of the run from the log's 'Loop time' line ({} if none)."""
    log = Path(log)
    match = re.search(
        r"Loop time of ([\d.eE+-]+) on \d+ procs for (\d+) steps with (\d+) atoms",
        log.read_text(errors="replace") if log.exists() else "",
    )
    if match is None:
        return {}
    seconds, steps, atoms = float(match.group(1)), int(match.group(2)), int(match.group(3))
    return {"wall_time_s": seconds, "particle_steps_per_second": steps * atoms / max(seconds, 1e-12)}


def read_dump_frames(folder: str | os.PathLike, n_frames: int, n_particles: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions [n_frames, N, 2] float32 (m) and radius [N] (m) from `dump custom` files
    frame.<step>.txt in `folder`, atoms sorted by id. Missing frames, truncated or foreign files
    raise EngineError naming the file (and line)."""
    folder = Path(folder)
    files = sorted(folder.glob("frame.*.txt"), key=_step_of)
    if len(files) != n_frames:
        raise read_error(
            folder,
            f"expected {n_frames} dump frames, found {len(files)} (the run stopped early or belongs to another case)",
        )
    positions = np.empty((n_frames, n_particles, 2), np.float32)
    radius = None
    for k, path in enumerate(files):
        frame = read_dump_file(path, n_particles)
        positions[k] = frame[:, 2:4]
        if radius is None:
            radius = frame[:, 4].copy()
    return positions, radius


def _step_of(path: Path) -> int:
    try:
        return int(path.name.split(".")[1])
    except (IndexError, ValueError):
        raise read_error(path, "not a frame.<step>.txt dump file") from None


def read_dump_file(path: str | os.PathLike, n_particles: int) -> np.ndarray:
    """One `dump custom` frame: [N, len(DUMP_COLUMNS)] float64 rows sorted by atom id (SI units:
    positions and radius in m, mass in kg)."""
    path = Path(path)
    lines = path.read_text(errors="replace").splitlines()
    expected = {0: "ITEM: TIMESTEP", 2: "ITEM: NUMBER OF ATOMS", 4: "ITEM: BOX BOUNDS"}
    for line_no, head in expected.items():
        if len(lines) <= line_no or not lines[line_no].startswith(head):
            raise read_error(path, f"line {line_no + 1}: expected {head!r}; not a LIGGGHTS dump custom file")
    try:
        count = int(lines[3])
    except ValueError:
        raise read_error(path, f"line 4: number of atoms {lines[3]!r} is not an integer") from None
    if count != n_particles:
        raise read_error(path, f"line 4: {count} atoms, the case has {n_particles}")
    columns = lines[8].split()[2:] if len(lines) > 8 and lines[8].startswith("ITEM: ATOMS") else None
    if columns != list(DUMP_COLUMNS):
        raise read_error(
            path,
            f"line 9: expected 'ITEM: ATOMS {' '.join(DUMP_COLUMNS)}', got "
            f"{lines[8] if len(lines) > 8 else 'end of file'!r}",
        )
    rows = lines[9:]
    if len(rows) != count:
        raise read_error(path, f"truncated: {len(rows)} atom lines after line 9, header says {count}")
    table = np.empty((count, len(DUMP_COLUMNS)))
    for i, row in enumerate(rows):
        fields = row.split()
        try:
            if len(fields) != len(DUMP_COLUMNS):
                raise ValueError(f"{len(fields)} columns, expected {len(DUMP_COLUMNS)}")
            table[i] = [float(v) for v in fields]
        except ValueError as exc:
            raise read_error(path, f"line {i + 10}: unreadable atom line ({exc})") from None
    table = table[np.argsort(table[:, 0])]
    if not np.array_equal(table[:, 0], np.arange(1, count + 1)):
        raise read_error(path, "atom ids are not 1..N")
    if not np.all(np.isfinite(table)):
        raise read_error(path, "non-finite values")
    return table
