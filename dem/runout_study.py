"""Which runout method to trust: every method of dem.runout read off the same DEM runs.

A runout method is judged by what it does with the chaos of a collapse, not by its value alone:
- packing scatter: the std of L* between packings of the same case (new seed, new settled
  packing), per phase of the collapse (free fall t/t* <= 1, spreading <= 2.5, stopping after,
  the paper's section 3). Scatter is what a calibration has to average away.
- flicker: the largest backward jump of L* from one frame to the next, in L*. A front of grains
  does not move back; a jump back is the rule losing grains (a chain breaking), not physics.
- chaos floor (benchmarks/gns_floor.py): the run rerun from its own settled packing with every grain
  moved by `perturbation` mean diameters. rerun_mse: a second run against the first (what an
  exact copy of the DEM would score); ideal_mse: the variance across runs (what the best
  deterministic surrogate, the mean curve, would score).
Used by the DAG's `runout_methods` rule (pipeline/runout.py: report table) and
benchmarks/runout_methods.py (JSON).
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

import numpy as np

from dem.runout import METHODS, RunoutMethod

if TYPE_CHECKING:
    from dem.case import CollapseCase
    from dem.trajectory import Trajectory

log = logging.getLogger(__name__)
PHASES = {"free_fall": (0.0, 1.0), "spreading": (1.0, 2.5), "stopping": (2.5, np.inf)}  # t/t*, paper section 3
PACKINGS = 8  # packings per case for the scatter (the issue asks for at least 8)
RERUNS = 8  # perturbed reruns per case for the chaos floor
PERTURBATION = 1e-3  # mean grain diameters (the chaos floor's perturbation)


def case_of(trajectory: Trajectory) -> CollapseCase:
    """The dem.case.CollapseCase a builtin trajectory was run for, from its attributes."""
    from dem.case import CollapseCase, Material

    a = trajectory.attrs
    fields = {f.name: a[f.name] for f in dataclasses.fields(CollapseCase) if f.name in a and f.name != "material"}
    return CollapseCase(material=Material.from_attrs(a), **fields)


def phase_means(t: np.ndarray, values: np.ndarray) -> dict:
    """Mean of values [T] over each phase of t/t* [T] (phases with no frame are left out)."""
    return {
        name: float(np.mean(values[(t > lo) & (t <= hi)]))
        for name, (lo, hi) in PHASES.items()
        if np.any((t > lo) & (t <= hi))
    }


def packing_runs(
    case: CollapseCase, n_packings: int = PACKINGS, after_run: Callable[[], None] | None = None
) -> list[Trajectory]:
    """n_packings builtin runs of `case`, packing seeds case.seed + 1000 + j (each settles its own).
    after_run: called with no argument after each run (progress)."""
    from dem.engines import BUILTIN, simulate_case

    runs = []
    for j in range(n_packings):
        runs.append(simulate_case(case.replace(seed=case.seed + 1000 + j, name=f"{case.name}_packing_{j}"), BUILTIN))
        if after_run:
            after_run()
    return runs


def perturbed_reruns(
    trajectory: Trajectory,
    n_reruns: int = RERUNS,
    perturbation: float = PERTURBATION,
    seed: int = 0,
    after_run: Callable[[], None] | None = None,
) -> list[Trajectory]:
    """n_reruns builtin reruns of a builtin trajectory from its own first frame, every grain moved
    by a normal of std `perturbation` mean diameters (seeded). after_run: as packing_runs."""
    from dem.engines import BUILTIN, simulate_case  # reruns of builtin runs, moved by 0.001 d
    from dem.trajectory import Trajectory

    case = case_of(trajectory)
    rng = np.random.default_rng(seed)
    diameter = 2.0 * float(np.mean(trajectory.radius))
    runs = []
    for _ in range(n_reruns):
        moved = trajectory.positions[:1] + rng.normal(0.0, perturbation * diameter, trajectory.positions[:1].shape)
        packing = Trajectory(
            moved.astype(np.float32), trajectory.radius, trajectory.particle_type, dict(trajectory.attrs)
        )
        runs.append(simulate_case(case, BUILTIN, packing=packing))
        if after_run:
            after_run()
    return runs


def method_statistics(t: np.ndarray, curves: np.ndarray) -> dict:
    """Packing scatter per phase, flicker and final L* of one case's runs read by one method.

    t [T] t/t*; curves [P, T]: L* of P packings. Scatter: std of L* across packings (ddof 1) per
    frame, averaged over each phase. Flicker: the largest backward step of L* between frames,
    over every run.
    """
    std = np.std(curves, axis=0, ddof=1)
    return {
        "packings": len(curves),
        "scatter_by_phase": phase_means(t, std),
        "scatter_mean": float(np.mean(std)),
        "flicker": float(max(0.0, np.max(-np.diff(curves, axis=1)))),
        "final_mean": float(curves[:, -1].mean()),
        "final_std": float(curves[:, -1].std(ddof=1)),
    }


def chaos_floor(t: np.ndarray, first: np.ndarray, others: np.ndarray, gns: np.ndarray | None = None) -> dict:
    """The chaos floor of one case read by one method (see the module text).

    t [T] t/t*; first [T]: L* of the run; others [R, T]: its perturbed reruns; gns [T] or None: a
    GNS rollout of the run, then also scored against the run and against the mean of all runs.
    """
    runs = np.vstack([first, others])
    variance = np.var(runs, axis=0, ddof=1)  # [T], across the realisations
    out = {
        "rerun_mse": float(np.mean((others - first) ** 2)),
        "rerun_mse_each": [float(np.mean((r - first) ** 2)) for r in others],
        "ideal_mse": float(np.mean(variance)),
        "ideal_mse_by_phase": phase_means(t, variance),
        "final_runout_spread": float(np.std(runs[:, -1], ddof=1)),
    }
    if gns is not None:
        out.update(
            gns_mse=float(np.mean((gns - first) ** 2)),
            gns_mse_to_mean=float(np.mean((gns - runs.mean(0)) ** 2)),
            gns_mse_by_phase=phase_means(t, (gns - first) ** 2),
        )
    return out


def compare_methods(
    cases: dict,
    methods: Iterable[RunoutMethod | dict | str] = METHODS,
    n_packings: int = PACKINGS,
    n_reruns: int = RERUNS,
    perturbation: float = PERTURBATION,
    rollouts: dict | None = None,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
) -> tuple[dict, dict]:
    """Every method on every case: (study, curves). study: {"cases": {label: {method: statistics
    (+ floor)}}, "mean": {method: ...}, settings}; curves: {label: {method: (t [T], L* [P, T])}} of
    the packings (for the figure).

    cases: {label: builtin DEM trajectory}: the scatter comes from n_packings new packings of its
    case, the chaos floor from n_reruns perturbed reruns of the trajectory itself (0: no floor).
    rollouts: {label: GNS rollout of that trajectory}, scored against the floor where given (a
    rollout with another frame count is left out). methods: names or RunoutMethods (with their
    parameters). progress: callable(fraction of the DEM runs done), e.g. dem.progress.progress_logger.
    """
    methods = [RunoutMethod.from_config(m) for m in methods]
    total, done = len(cases) * (n_packings + n_reruns), [0]

    def after_run():
        done[0] += 1
        if progress:
            progress(done[0] / total)

    out, curves = {}, {}
    for k, (label, trajectory) in enumerate(cases.items()):
        packings = packing_runs(case_of(trajectory), n_packings, after_run)
        reruns = perturbed_reruns(trajectory, n_reruns, perturbation, seed + k, after_run) if n_reruns else []
        rollout = (rollouts or {}).get(label)
        if rollout is not None and rollout.n_frames != trajectory.n_frames:
            rollout = None
        t = trajectory.t_over_tstar
        out[label], curves[label] = {}, {}
        for method in methods:  # every run is read once per method
            packing_curves = _curves(method, packings)
            curves[label][method.method] = (t, packing_curves)
            row = method_statistics(t, packing_curves)
            if reruns:
                gns = None if rollout is None else _curves(method, [rollout])[0]
                row["floor"] = chaos_floor(t, _curves(method, [trajectory])[0], _curves(method, reruns), gns)
            out[label][method.method] = row
        log.info("%s: %s", label, {m: round(r["scatter_mean"], 3) for m, r in out[label].items()})
    return {
        "methods": [m.to_config() for m in methods],
        "n_packings": n_packings,
        "n_reruns": n_reruns,
        "perturbation_diameters": perturbation,
        "cases": out,
        "mean": _means(out, methods),
    }, curves


def _curves(method: RunoutMethod, runs) -> np.ndarray:
    """[R, T] L* of R trajectories read by `method`."""
    return np.array([method.curve(r)[1] for r in runs])


def _means(cases: dict, methods) -> dict:
    """Per method, each statistic averaged over the cases (flicker: the largest)."""
    means = {}
    for method in methods:
        rows = [c[method.method] for c in cases.values()]
        mean = {
            "scatter_mean": float(np.mean([r["scatter_mean"] for r in rows])),
            "flicker": float(np.max([r["flicker"] for r in rows])),
            # phases no case's runs reach (short runs: no stopping phase) are left out, as in phase_means
            "scatter_by_phase": {
                p: float(np.mean([r["scatter_by_phase"][p] for r in rows if p in r["scatter_by_phase"]]))
                for p in PHASES
                if any(p in r["scatter_by_phase"] for r in rows)
            },
        }
        floors = [r["floor"] for r in rows if "floor" in r]
        for key in ("rerun_mse", "ideal_mse", "gns_mse", "gns_mse_to_mean"):
            values = [f[key] for f in floors if key in f]  # the GNS's: the cases with a rollout
            if values:
                mean[key] = float(np.mean(values))
        mean["gns_cases"] = sum("gns_mse" in f for f in floors)
        means[method.method] = mean
    return means


def markdown_table(study: dict) -> str:
    """The per-method table of compare_methods (means over its cases)."""
    lines = [
        "| method | L* scatter between packings: free fall / spreading / stopping | largest backward jump "
        "(L*) | chaos floor: rerun MSE / ideal MSE | GNS MSE: against the run / against the mean of runs |",
        "|---|---|---|---|---|",
    ]
    for name, m in study["mean"].items():
        by_phase = m["scatter_by_phase"]
        phases = " / ".join(f"{by_phase[p]:.3f}" if p in by_phase else "-" for p in PHASES)
        floor = f"{m['rerun_mse']:.3f} / {m['ideal_mse']:.3f}" if "rerun_mse" in m else "-"
        gns = f"{m['gns_mse']:.3f} / {m['gns_mse_to_mean']:.3f} ({m['gns_cases']} cases)" if "gns_mse" in m else "-"
        lines.append(f"| {name} | {phases} | {m['flicker']:.3f} | {floor} | {gns} |")
    return "\n".join(lines)


def plot_methods(curves: dict, path: str | os.PathLike) -> None:
    """L*(t/t*) of every packing of each case, one panel per case, one colour per method.
    curves: compare_methods' {label: {method: (t [T], L* [P, T])}}."""
    from dem.plots import plt, save_figure

    fig, axes = plt.subplots(1, len(curves), figsize=(4.4 * len(curves), 3.8), squeeze=False)
    colours = dict(zip(METHODS, ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=True))
    for ax, (label, by_method) in zip(axes[0], curves.items(), strict=True):
        for method, (t, packing_curves) in by_method.items():
            for j, curve in enumerate(packing_curves):
                ax.plot(t, curve, color=colours[method], lw=0.7, alpha=0.6, label=method if j == 0 else None)
        ax.set(title=label, xlabel="t / t*", ylabel="L*")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("runout of every packing, read by each method", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
