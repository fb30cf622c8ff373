"""The engine interface: render a deck for a case, run it, read its output into a Trajectory.

Every engine (builtin, LIGGGHTS, MFIX) starts the collapse from the same settled packing (a
one-frame Trajectory from dem.packing.settle_column), so that differences between engines come
from the solvers, not from the packings. An engine works in its own folder `work_dir`:

    deck = engine.render(case, packing, work_dir)   # input files; returns the main deck's path
    engine.run(deck, progress)                      # the solver, log kept in work_dir
    trajectory = engine.read(case, packing, work_dir)

`engine.simulate(...)` does the three in turn. The solver engines (LIGGGHTS, MFIX) share the
render / run template of SolverEngine and only add their deck, command line and output reader.
Helpers shared by the solver engines live here too: running a subprocess with its log kept, and
binning polydisperse grains into size classes so that per-class damping keeps the restitution
coefficient within a tolerance.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from dem.case import CollapseCase
from dem.packing import check_grain_count, settle_column
from dem.trajectory import GRAIN, Trajectory, TrajectoryError, engine_attrs, write_trajectory

LOG_TAIL_LINES = 25


class EngineError(RuntimeError):
    """A solver failed, is missing, or wrote output that cannot be read; the message says which
    file (deck, log, output) and why."""


class EngineNotInstalled(EngineError):
    """An engine asked for by name whose solver is not installed; the message says how to install it."""


class Engine:
    """One DEM engine. Subclasses set `name`, `install_hint` and implement render/run/read."""

    name = "engine"
    executable = None  # default solver command (looked up on PATH) or None for in-process
    install_hint = ""
    mechanisms: tuple[str, ...] = ()  # candidate-mechanism case fields (MECHANISMS) it can run
    resume_files: tuple[str, ...] = ()  # files in work_dir a rerun of a killed run resumes from

    def __init__(self, solver_path: str | None = None, threads: int = 1):
        """solver_path: the solver executable (path or command name); None: `executable` on PATH.
        threads: cores one run may use (config dem.threads); engines that run serially ignore it."""
        self.solver_path = solver_path
        self.threads = threads

    # -- availability ---------------------------------------------------------------------------
    def find_solver(self) -> str | None:
        """Absolute path of the solver executable, or None when it cannot be found."""
        command = self.solver_path or self.executable
        if command is None:
            return None
        return shutil.which(str(command))

    def availability(self) -> tuple[bool, str]:
        """(available, why): whether this engine can run here, in words."""
        path = self.find_solver()
        where = self.solver_path or self.executable
        if path is None:
            return (
                False,
                f"{self.name}: solver {where!r} not found ({'configured path' if self.solver_path else 'not on PATH'})",
            )
        return True, f"{self.name}: solver found at {path}"

    def require_solver(self) -> str:
        path = self.find_solver()
        if path is None:
            where = self.solver_path or self.executable
            raise EngineNotInstalled(
                f"engine {self.name!r} was asked for but its solver {where!r} is not "
                f"installed or not executable. {self.install_hint}"
            )
        return path

    def version(self) -> str:
        return "unknown"

    # -- the three steps ------------------------------------------------------------------------
    def render(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Path:
        """Write the input files for `case` starting from `packing` into work_dir; the deck path."""
        raise NotImplementedError

    def run(self, deck: Path, progress: Callable[[float], None] | None = None) -> None:
        """Run the solver on `deck` (in its folder), log kept beside it. progress: callable(fraction)."""
        raise NotImplementedError

    def read(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Trajectory:
        """The solver's output in work_dir as a Trajectory (case.n_frames frames)."""
        raise NotImplementedError

    def simulate(
        self,
        case: CollapseCase,
        packing: Trajectory | None,
        work_dir: str | os.PathLike,
        progress: Callable[[float], None] | None = None,
        output: str | os.PathLike | None = None,
    ) -> Trajectory:
        """Render, run and read; write the trajectory HDF5 to `output` when given.

        packing None: settle the column with the builtin settling step first.
        """
        if packing is None:
            packing = settle_column(case)
        check_packing(case, packing)
        deck = self.render(case, packing, work_dir)
        self.run(deck, progress)
        return self.collect(case, packing, work_dir, output)

    def collect(
        self,
        case: CollapseCase,
        packing: Trajectory,
        work_dir: str | os.PathLike,
        output: str | os.PathLike | None = None,
    ) -> Trajectory:
        """Read the solver's output in work_dir; write it to `output` (HDF5) only when it reads whole."""
        trajectory = self.read(case, packing, work_dir)
        if output is not None:
            write_trajectory(output, trajectory)
        return trajectory


class SolverEngine(Engine):
    """An engine that runs an external solver (LIGGGHTS, MFIX): the render / run template.

    render writes two files into work_dir, the deck (`deck_file`) and the grains it reads
    (`grains_file`), both from the subclass's render_files, after removing stale frames of an
    earlier run; run starts `command` on the deck, log in `log_file`, counts the frames written
    (files `frame_glob` in `frames_dir`, relative to work_dir) for progress, and fails when fewer
    than the deck's header line `# frames: N` were written. read stays the subclass's.
    """

    deck_file = "deck"
    grains_file = "grains"
    log_file = "solver.log"
    frames_dir = "."
    frame_glob = "*"

    def render_files(self, case: CollapseCase, packing: Trajectory) -> tuple[str, str]:
        """(deck text, grains file text) for `case` starting from the last frame of `packing`."""
        raise NotImplementedError

    def command(self, solver: str, deck: Path) -> list[str]:
        """The solver's command line for `deck`, run in the deck's folder."""
        raise NotImplementedError

    def render(self, case: CollapseCase, packing: Trajectory, work_dir: str | os.PathLike) -> Path:
        """Write the deck and the grains file into work_dir (created), stale frames removed; the deck path."""
        work_dir = Path(work_dir)
        frames = work_dir / self.frames_dir
        frames.mkdir(parents=True, exist_ok=True)
        for old in frames.glob(self.frame_glob):
            old.unlink()  # stale frames of an earlier run would be read as this run's
        deck_text, grains_text = self.render_files(case, packing)
        (work_dir / self.grains_file).write_text(grains_text)
        deck = work_dir / self.deck_file
        deck.write_text(deck_text)
        return deck

    def run(self, deck: Path, progress: Callable[[float], None] | None = None) -> None:
        """Run the solver on `deck` in its folder; progress(fraction of the deck's frames written)."""
        solver = self.require_solver()
        deck = Path(deck)
        n_frames = int(re.search(r"^# frames: (\d+)", deck.read_text(), re.M).group(1))
        frames = deck.parent / self.frames_dir
        log = deck.parent / self.log_file

        def written() -> int:
            return len(list(frames.glob(self.frame_glob)))

        run_solver(self.command(solver, deck), deck, log, self.name, progress, lambda: written() / n_frames)
        check_frames_written(self.name, deck, log, written(), n_frames)

    def grain_trajectory(
        self, case: CollapseCase, positions: np.ndarray, radius: np.ndarray, **attrs: object
    ) -> Trajectory:
        """Frames read from the solver's output as a Trajectory of grains: positions [T, N, 2] (m),
        radius [N] (m); attrs: the case's and this engine's (dem.trajectory.engine_attrs), then `attrs`."""
        all_attrs = engine_attrs(case, self.name, self.version())
        all_attrs.update(attrs)
        return Trajectory(
            positions=positions, radius=radius, particle_type=np.full(len(radius), GRAIN, np.int32), attrs=all_attrs
        )


def check_packing(case: CollapseCase, packing: Trajectory) -> None:
    """The packing must hold the case's grains inside its box [0, case.box_width] x [0, ...] (m)."""
    check_grain_count(case, packing)
    x = packing.positions[-1]
    if x[:, 0].min() < 0 or x[:, 0].max() > case.box_width or x[:, 1].min() < 0:
        raise TrajectoryError(
            f"packing for case {case.name or '?'}: grains outside the box [0, {case.box_width}] x [0, ...]"
        )


# -- running a solver ----------------------------------------------------------------------------
def tail(path: str | os.PathLike, n: int = LOG_TAIL_LINES) -> str:
    """The last n lines of a text file ('' when it does not exist)."""
    path = Path(path)
    if not path.exists():
        return ""
    lines = path.read_text(errors="replace").splitlines()
    return "\n".join(lines[-n:])


def run_solver(
    command: list[str],
    deck: Path,
    log: Path,
    name: str,
    progress: Callable[[float], None] | None = None,
    progress_of: Callable[[], float] | None = None,
    poll_s: float = 0.5,
) -> None:
    """Run `command` in the deck's folder, stdout and stderr to `log`.

    progress_of: callable() -> fraction done (e.g. from output files counted), polled every
    poll_s and passed to `progress`. A non-zero exit raises EngineError with the deck path and the
    log's last lines.
    """
    deck = Path(deck)
    if shutil.which("stdbuf"):
        # line-buffered output: a solver that aborts through MPI_Abort otherwise loses its last
        # (error) lines, still sitting in the stdio buffer
        command = ["stdbuf", "-oL", "-eL", *command]
    with open(log, "w") as log_file:
        try:
            process = subprocess.Popen(
                command, cwd=deck.parent, stdout=log_file, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
            )
        except OSError as exc:
            raise EngineError(f"{name}: could not start {command[0]!r} for deck {deck}: {exc}") from exc
        while process.poll() is None:
            time.sleep(poll_s)
            if progress is not None and progress_of is not None:
                progress(min(1.0, progress_of()))
    if process.returncode != 0:
        raise EngineError(
            f"{name} failed (exit status {process.returncode}) on deck {deck}; log {log}, last lines:\n{tail(log)}"
        )


def check_frames_written(name: str, deck: Path, log: Path, written: int, expected: int) -> None:
    """A solver that exited cleanly but wrote too few frames fails like a crash: deck, log tail."""
    if written != expected:
        raise EngineError(
            f"{name} wrote {written} of {expected} output frames for deck {deck}; log {log}, last lines:\n{tail(log)}"
        )


# -- polydisperse grains: size classes for per-pair damping -------------------------------------
def restitution_from_damping_ratio(ratio: float | np.ndarray) -> np.ndarray:
    """e of a linear spring-dashpot with damping ratio zeta = eta / (2 sqrt(m_eff kn))."""
    ratio = np.asarray(ratio, float)
    return np.exp(-math.pi * ratio / np.sqrt(1.0 - ratio**2))


def damping_ratio(restitution: float) -> float:
    """zeta = |ln e| / sqrt(pi^2 + ln^2 e) (the builtin's `restitution_factor`)."""
    log_e = abs(math.log(restitution))
    return log_e / math.sqrt(math.pi**2 + log_e**2)


def worst_restitution_error(restitution: float, mass_factor: float) -> float:
    """Largest relative error of e when damping is computed for an m_eff off by a factor within
    [1/mass_factor, mass_factor]: the damping ratio is then off by up to sqrt(mass_factor)."""
    zeta = damping_ratio(restitution)
    if restitution >= 1.0:
        return 0.0
    off = math.sqrt(mass_factor)
    errors = restitution_from_damping_ratio(np.minimum([zeta * off, zeta / off], 0.999999)) / restitution - 1.0
    return float(np.max(np.abs(errors)))


def size_classes(
    mass: np.ndarray, restitutions: Sequence[float], tolerance: float, max_classes: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """Bin grains into classes of equal width in log(mass) so that damping computed per class pair
    (from the classes' geometric-mean masses) keeps every contact's restitution within `tolerance`
    (relative), using as few classes as that needs (at most max_classes).

    m_eff = m_i m_j / (m_i + m_j) is increasing and of degree one in both masses, so when every
    mass is within a factor q of its class mass, every pair's (and wall contact's) m_eff is within
    the factor q of the class pair's; the damping ratio is then within sqrt(q), which bounds the
    error in e (see worst_restitution_error).

    mass [N] (kg). Returns (class_index [N] int, class_mass [K] kg, worst relative error in e).
    """
    mass = np.asarray(mass, float)
    log_lo, log_hi = math.log(mass.min()), math.log(mass.max())
    span = log_hi - log_lo
    for n_classes in range(1, max_classes + 1):
        q = math.exp(span / (2 * n_classes))
        worst = max(worst_restitution_error(e, q) for e in restitutions)
        if worst <= tolerance:
            break
    width = span / n_classes if span > 0 else 1.0
    # the scalar math library, not numpy's vector exp and log: those are compiled per instruction set
    # (AVX-512 has its own), so a deck would differ in its last digits from machine to machine
    index = np.array([min(int((math.log(m) - log_lo) / width), n_classes - 1) for m in mass.tolist()], int)
    centres = [math.exp(log_lo + (k + 0.5) * width) for k in range(n_classes)] if span > 0 else [float(mass[0])]
    return index, np.array(centres), worst


def read_error(path: str | os.PathLike, what: str) -> EngineError:
    """A clear error for an output file that is truncated or not the solver's."""
    return EngineError(f"{path}: {what}; no trajectory written")


# -- cross-validation -----------------------------------------------------------------------------
def runout_agreement(runout: np.ndarray, runout_reference: np.ndarray) -> dict:
    """How well a runout curve L*(t/t*) [T] reproduces a reference one [T] at the same frame times
    (same case and packing, or the means over the same packings, from another engine).

    Returns the final runout L* of both, the relative difference of the final runouts
    (L*_final - L*_ref,final) / L*_ref,final, and the RMS difference of the two curves over the
    reference's final runout.
    """
    runout, runout_reference = np.asarray(runout, float), np.asarray(runout_reference, float)
    if runout.shape != runout_reference.shape:
        raise ValueError(
            f"runout_agreement: curves of {runout.shape} and {runout_reference.shape} frames: not the same case"
        )
    final, final_ref = float(runout[-1]), float(runout_reference[-1])
    return {
        "final_runout": final,
        "final_runout_reference": final_ref,
        "final_relative_difference": (final - final_ref) / final_ref,
        "rms_curve_difference_over_final": float(np.sqrt(np.mean((runout - runout_reference) ** 2)) / abs(final_ref)),
    }


# Case fields beyond the paper's contact model (candidate mechanisms), with their "off" values.
MECHANISMS = ("rolling_friction", "cohesion_energy", "friction_base", "sidewall_friction", "gate_lift_speed")


def refuse_unsupported(case: CollapseCase, engine: str, supported: Iterable[str] = ()) -> None:
    """EngineError naming the mechanisms `case` switches on that `engine` does not model.

    friction_base counts as on only when it differs from the side walls' friction.
    """
    on = {
        "rolling_friction": case.rolling_friction > 0,
        "cohesion_energy": case.cohesion_energy > 0,
        "friction_base": case.resolved_friction_base != case.resolved_friction_wall,
        "sidewall_friction": case.sidewall_friction > 0,
        "gate_lift_speed": case.gate_lift_speed > 0,
    }
    missing = [name for name in MECHANISMS if on[name] and name not in supported]
    if missing:
        raise EngineError(
            f"case {case.name or '?'}: engine {engine!r} does not model {', '.join(missing)} "
            f"(it models {', '.join(supported) or 'none of the candidate mechanisms'}); "
            "run such cases with dem.engine: builtin"
        )
