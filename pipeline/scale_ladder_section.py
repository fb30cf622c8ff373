"""The scale ladder's report section (results/report/scale_ladder.md): the runout per size_scale,
its packing scatter and the trend (pipeline/scale_ladder.py computes the summary it reads)."""

from __future__ import annotations

from dem.runout import RunoutMethod
from dem.scale_ladder import scale_label


def _value(stats: dict, digits: int) -> str:
    """`mean +- std` of a scatter() entry; `mean` alone for one packing; `n/a` when unknown."""
    if stats["mean"] is None:
        return "n/a"
    if stats["std"] is None:
        return f"{stats['mean']:.{digits}f}"
    return f"{stats['mean']:.{digits}f} +- {stats['std']:.{digits}f}"


def section_text(summary: dict, title: str, runout: RunoutMethod, json_path: str, figure: str) -> str:
    """The report section: what ran, the table per size_scale, the trend in one sentence, the figure."""
    by_scale = summary["by_size_scale"]
    read_at = sorted({x for entry in by_scale.values() for x in entry["runout_at"]}, key=float)
    counts = sorted({len(entry["seeds"]) for entry in by_scale.values()})
    packings = (
        "1 packing each" if counts == [1] else f"{' or '.join(map(str, counts))} packings each, their scatter after +-"
    )
    header = ["size_scale", "grains (across)"] + [f"L* at t/t* = {x}" for x in read_at]
    header += ["final L*", "final height / H_i", "s per run (settle + collapse)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for label, entry in by_scale.items():
        at = [_value(entry["runout_at"][x], 2) if x in entry["runout_at"] else "" for x in read_at]
        cost = " + ".join(
            "n/a" if s["mean"] is None else f"{s['mean']:.3g}" for s in (entry["settle_s"], entry["collapse_s"])
        )
        cells = [label, f"{entry['n_particles']:,} ({entry['grains_across']:.1f})", *at]
        cells += [_value(entry["final_runout"], 2), _value(entry["final_height_over_H_i"], 3), cost]
        lines.append("| " + " | ".join(cells) + " |")
    coarse, fine = next(iter(by_scale.values())), list(by_scale.values())[-1]
    if len(by_scale) > 1:
        change = fine["final_runout"]["mean"] / coarse["final_runout"]["mean"] - 1
        trend = (
            f"From size_scale {scale_label(coarse['size_scale'])} to {scale_label(fine['size_scale'])} the final "
            f"L* goes from {coarse['final_runout']['mean']:.2f} to {fine['final_runout']['mean']:.2f} "
            f"({change:+.0%}) and the final deposit height from {coarse['final_height_over_H_i']['mean']:.3f} "
            f"to {fine['final_height_over_H_i']['mean']:.3f} H_i. "
        )
    else:
        trend = "One size_scale only: no trend to read. "
    text = [
        f"How the runout depends on grain size: {title}, run at size_scale "
        f"{', '.join(by_scale)} ({packings}), "
        f"L* read as the **{runout.label}**, the final values at the last frame "
        f"(t/t* = {coarse['final_t_over_tstar']:.3g}). "
        + trend
        + "Where the values part by more than their packing scatter, parameters calibrated at one size_scale "
        "are effective values of that scale. Seconds per run: the mean settle and collapse alone (no job "
        f"overhead). Per packing in `{json_path}`.",
        "",
        "\n".join(lines),
        "",
        f"![L*(t/t*) per size_scale and the final deposit against size_scale]({figure})",
        "",
    ]
    return "\n".join(text)
