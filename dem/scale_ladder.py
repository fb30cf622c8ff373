"""How the runout changes with grain size: one column and parameter set at several size_scale.

Coarse graining (`size_scale`) swells the grains of a column of fixed L_i and a, so a coarse column
is fewer grains across; its runout is shorter and its deposit higher (docs/experiments/grain-size.md). A
scale ladder runs one column at several size_scale, on a few packings each, and reads every run
the same way. It runs in the DAG as rows of the case table (dataset `scale_ladder`,
workflow/rules/scale_ladder.smk; stage layer pipeline/scale_ladder.py) and alone in
benchmarks/scale_ladder.py; both build, read, summarise and draw it here:

    case_rows (the runs) -> read_run (one run: L*(t/t*), final height, cost) -> summarise -> plot_ladder
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from dem.grid import case_from_row
from dem.runout import RunoutMethod, final_height
from dem.runout_study import case_of

if TYPE_CHECKING:
    from dem.trajectory import Trajectory

DATASET = "scale_ladder"  # the ladder's dataset in the case table (results/dem/scale_ladder/)
READ_AT = (1.0, 2.0, 3.5, 4.0)  # t/t* at which L* is reported (those inside the runs)
# The ladder's column and parameters (config section scale_ladder): one value for every run.
CASE_KEYS = ("material", "L_i", "aspect_ratio", "friction", "restitution", "duration_over_tstar")


def case_id(size_scale: float, packing: int) -> str:
    """`scale1p5_packing0`: the case id of packing `packing` at `size_scale` (no dot: a wildcard)."""
    return f"scale{size_scale:g}_packing{packing}".replace(".", "p")


def case_rows(spec: Mapping, dataset: str = DATASET) -> list[dict]:
    """Case-table rows (dem.grid format) of a ladder, coarsest first.

    spec: the config's scale_ladder section: size_scales, packings, seed and the column (CASE_KEYS).
    Packing k of every size_scale is settled from seed `seed + k`. Each row is checked by building its
    CollapseCase (dem.case.CaseError naming the field).
    """
    rows = []
    for size_scale in sorted(spec["size_scales"], reverse=True):
        for k in range(spec["packings"]):
            row = {
                "dataset": dataset,
                "case_id": case_id(size_scale, k),
                "split": "scale_ladder",
                **{key: spec[key] for key in CASE_KEYS},
                "seed": int(spec["seed"]) + k,
                "size_scale": float(size_scale),
            }
            row["material"] = case_from_row(row).material.to_config()
            rows.append(row)
    return rows


@dataclasses.dataclass(frozen=True)
class LadderRun:
    """One run of a ladder as read: its runout curve by the configured method, the final deposit
    height and its cost (None where the file does not say)."""

    size_scale: float
    seed: int
    n_particles: int
    grains_across: float
    t_over_tstar: np.ndarray  # [T]
    runout: np.ndarray  # [T] L* = (L - L_i) / L_i
    final_height_over_H_i: float  # highest point of the connected deposit at the last frame / H_i
    settle_s: float | None  # wall seconds of the settle (the packing's wall_time_s)
    collapse_s: float | None  # wall seconds of the collapse (the trajectory's wall_time_s)
    particle_steps_per_second: float | None  # of the collapse


def read_run(trajectory: Trajectory, runout: RunoutMethod | dict | str, settle_s: float | None = None) -> LadderRun:
    """A ladder run read off its trajectory (L* by `runout`, the configured method); settle_s: the
    settle's wall seconds (its packing's attribute wall_time_s), None when unknown."""
    case = case_of(trajectory)
    t, curve = RunoutMethod.from_config(runout).curve(trajectory)
    height = final_height(np.asarray(trajectory.positions[-1], np.float64), trajectory.radius)
    return LadderRun(
        size_scale=float(case.size_scale),
        seed=int(case.seed),
        n_particles=int(trajectory.n_particles),
        grains_across=float(case.grains_across),
        t_over_tstar=np.asarray(t, np.float64),
        runout=np.asarray(curve, np.float64),
        final_height_over_H_i=height / case.H_i,
        settle_s=_number(settle_s),
        collapse_s=_number(trajectory.attrs.get("wall_time_s")),
        particle_steps_per_second=_number(trajectory.attrs.get("particle_steps_per_second")),
    )


def _number(value) -> float | None:
    return None if value is None or not np.isfinite(float(value)) else float(value)


def scatter(values: Sequence[float | None]) -> dict:
    """{"mean", "std" (between packings, n - 1; None below 2), "per_packing"} of one value per
    packing; mean and std None when a value is unknown."""
    values = [None if v is None else float(v) for v in values]
    known = None not in values
    return {
        "mean": float(np.mean(values)) if known and values else None,
        "std": float(np.std(values, ddof=1)) if known and len(values) > 1 else None,
        "per_packing": values,
    }


def scale_label(size_scale: float) -> str:
    """The key of a size_scale in a summary: `5`, `1.5`."""
    return f"{size_scale:g}"


def summarise(runs: Sequence[LadderRun]) -> dict:
    """{size_scale label: summary} of a ladder's runs, coarsest first. Per size_scale: grains,
    grains across, seeds, L* at each READ_AT point inside the runs, the final L* and deposit height
    / H_i at the last frame (final_t_over_tstar) and the cost per run (settle and collapse seconds,
    particle-steps/s), each as scatter() over the packings."""
    by_scale: dict[float, list[LadderRun]] = {}
    for run in runs:
        by_scale.setdefault(run.size_scale, []).append(run)
    summary = {}
    for size_scale in sorted(by_scale, reverse=True):
        group = sorted(by_scale[size_scale], key=lambda r: r.seed)
        end = min(float(r.t_over_tstar[-1]) for r in group)
        summary[scale_label(size_scale)] = {
            "size_scale": size_scale,
            "n_particles": group[0].n_particles,
            "grains_across": group[0].grains_across,
            "seeds": [r.seed for r in group],
            "runout_at": {
                f"{x:g}": scatter([np.interp(x, r.t_over_tstar, r.runout) for r in group])
                for x in READ_AT
                if x <= end + 1e-9
            },
            "final_t_over_tstar": end,
            "final_runout": scatter([r.runout[-1] for r in group]),
            "final_height_over_H_i": scatter([r.final_height_over_H_i for r in group]),
            "settle_s": scatter([r.settle_s for r in group]),
            "collapse_s": scatter([r.collapse_s for r in group]),
            "particle_steps_per_second": scatter([r.particle_steps_per_second for r in group]),
        }
    return summary


def plot_ladder(summary: Mapping, runs: Sequence[LadderRun], path: str | os.PathLike, title: str = "") -> None:
    """Left: L*(t/t*) of every run, one colour per size_scale (thin: each packing, bold: their
    mean). Right: the final L* (each packing and the mean) and the mean final deposit height / H_i
    against size_scale. summary: summarise(runs)."""
    from dem.plots import plt, save_figure

    fig, (ax_curve, ax_scale) = plt.subplots(1, 2, figsize=(10, 4))
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(summary)))
    for colour, entry in zip(colours, summary.values(), strict=True):
        group = [r for r in runs if r.size_scale == entry["size_scale"]]
        for r in group:
            ax_curve.plot(r.t_over_tstar, r.runout, color=colour, alpha=0.35, lw=0.8)
        mean = np.mean([np.interp(group[0].t_over_tstar, r.t_over_tstar, r.runout) for r in group], axis=0)
        label = f"size_scale {scale_label(entry['size_scale'])}: {entry['n_particles']} grains, "
        ax_curve.plot(
            group[0].t_over_tstar, mean, color=colour, lw=1.8, label=f"{label}{entry['grains_across']:.1f} across"
        )
    ax_curve.set(xlabel="t / t*", ylabel="L* = (L - L_i) / L_i", title=title)
    ax_curve.grid(alpha=0.3)
    ax_curve.legend(fontsize=7)
    scales = [entry["size_scale"] for entry in summary.values()]
    final = [entry["final_runout"]["per_packing"] for entry in summary.values()]
    ax_scale.plot(np.repeat(scales, [len(f) for f in final]), np.concatenate(final), "o", color="C0", alpha=0.5)
    ax_scale.plot(scales, [np.mean(f) for f in final], "-", color="C0", label="final L* (dots: packings)")
    ax_scale.set(xlabel="size_scale (grain diameter / real)", ylabel="final L*", xscale="log")
    ax_scale.set_xticks(scales, [scale_label(s) for s in scales])
    ax_scale.minorticks_off()
    ax_scale.grid(alpha=0.3)
    twin = ax_scale.twinx()
    heights = [entry["final_height_over_H_i"]["per_packing"] for entry in summary.values()]
    twin.plot(scales, [np.mean(h) for h in heights], "s--", color="C3", label="final deposit height / H_i")
    twin.set_ylabel("final deposit height / H_i", color="C3")
    lines = ax_scale.get_legend_handles_labels()
    more = twin.get_legend_handles_labels()
    ax_scale.legend(
        lines[0] + more[0], lines[1] + more[1], fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2
    )
    ax_scale.set_title(f"at t/t* = {min(e['final_t_over_tstar'] for e in summary.values()):.3g}")
    fig.tight_layout()
    save_figure(fig, path)
