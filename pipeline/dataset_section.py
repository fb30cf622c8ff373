"""The dataset stage's report section (results/report/dataset.md): each DEM dataset's cases, grains,
frames and parameter ranges, with its summary figure (pipeline/dataset.py builds what it reads)."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

from dem.atomic import StrPath, write_text
from gns.dataset import SPLITS, load_dataset_metadata


def write_section(metadata_paths: Sequence[StrPath], summary_figures: Sequence[StrPath], out_path: StrPath) -> str:
    """Write the report section on the DEM datasets at `out_path` (dataset_section); returns its text."""
    text = dataset_section(metadata_paths, summary_figures, out_path)
    write_text(out_path, text)
    return text


def dataset_section(
    metadata_paths: Sequence[StrPath], summary_figures: Sequence[StrPath], fragment_path: StrPath
) -> str:
    """Markdown report section on the DEM datasets; figure links are relative to `fragment_path`."""
    where = Path(fragment_path).parent
    lines = [
        "DEM datasets built from the case table (one trajectory HDF5 per case).",
        "",
        "| dataset | cases train/valid/test | grains per case | frames | dt_frame (ms) | friction | "
        "restitution | L_i (mm) | a |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for meta_path in metadata_paths:
        m = load_dataset_metadata(meta_path)
        r = m["parameter_ranges"]
        n = {s: len(m["splits"][s]) for s in SPLITS}
        lines.append(
            f"| {m['name']} | {n['train']}/{n['valid']}/{n['test']} | {m['n_particles']['min']}-"
            f"{m['n_particles']['max']} | {m['sequence_length']}-{m.get('sequence_length_max', '')} | "
            f"{m['dt_frame'] * 1e3:.3g} | {_span(r['friction'])} | {_span(r['restitution'])} | "
            f"{_span([v * 1e3 for v in r['L_i']])} | {_span(r['aspect_ratio'])} |"
        )
    lines.append("")
    for meta_path, figure in zip(metadata_paths, summary_figures):
        name = Path(meta_path).parent.name
        lines += [f"![{name}: cases by split and runout curves]({os.path.relpath(figure, where)})", ""]
    return "\n".join(lines)


def _span(pair) -> str:
    return f"{pair[0]:.3g}" if math.isclose(pair[0], pair[1]) else f"{pair[0]:.3g}-{pair[1]:.3g}"
