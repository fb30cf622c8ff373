"""The case table: the config's datasets expanded into one row per DEM case.

A dataset in the config (see workflow/schemas/config.schema.yaml; validated by
pipeline.config.validate_config before it gets here) gives each case parameter as a fixed number,
`{values: [...]}` (levels) or `{range: [min, max]}` (continuous). Expansion:

1. Level combinations (full factorial of every `values` parameter) share the cases as evenly as
   possible; which combinations get one case more is drawn with the dataset seed.
2. Within each combination, `range` parameters are sampled by a Latin hypercube (seeded), so every
   combination covers each range evenly.
3. Cases are ordered by (levels, then range parameters) and dealt into train/valid/test by a smooth
   weighted round robin, so each split spans every level and the whole of every range
   ("balanced over the varied parameters"), and the split sizes match the fractions exactly.
4. `overrides` then change single cases ({case_id: {parameter: value}}) without touching the
   others, so editing one case reruns only that case's jobs.

Deterministic for a given config. A row is a flat dict: dataset, case_id, split, material, L_i,
aspect_ratio, friction, restitution, seed, size_scale, output_interval, and any other CollapseCase
field the dataset sets. `case_from_row` turns it into a `dem.case.CollapseCase`.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from dem.atomic import write_text
from dem.case import CaseError, CollapseCase

# Parameters that may vary over a dataset, in the order cases are sorted for the splits.
VARIED = ("aspect_ratio", "L_i", "friction", "restitution", "friction_wall", "restitution_wall")
# Dataset keys passed straight to CollapseCase (same value for every case).
FIXED = (
    "size_scale",
    "polydispersity",
    "duration_over_tstar",
    "normal_stiffness",
    "tangential_stiffness_ratio",
    "tangential_damping_ratio",
    "dt_over_contact_time",
    "box_width",
    "box_height",
)
SPLITS = ("train", "valid", "test")
SIGNIFICANT_DIGITS = 8  # sampled parameters are rounded so the table reads cleanly and reproduces exactly


class ConfigError(ValueError):
    """The config breaks the schema, a physical bound or a cross-key rule; the message names every
    bad key. Raised here for a case that cannot be simulated, and by pipeline.config (the config
    validation) for everything else."""


# --- expansion into cases --------------------------------------------------------------------
def case_id_of(index: int, n_cases: int) -> str:
    """`case_007`: zero-padded to at least 3 digits and to the width of n_cases - 1."""
    return f"case_{index:0{max(3, len(str(n_cases - 1)))}d}"


def split_counts(n_cases: int, fractions: dict) -> dict:
    """Cases per split: largest remainder of n_cases * fraction; every non-zero split gets >= 1."""
    exact = {s: n_cases * fractions[s] for s in SPLITS}
    counts = {s: int(math.floor(exact[s])) for s in SPLITS}
    for s in sorted(SPLITS, key=lambda s: exact[s] - counts[s], reverse=True)[: n_cases - sum(counts.values())]:
        counts[s] += 1
    for s in SPLITS:
        if fractions[s] > 0 and counts[s] == 0:
            counts[s] = 1
            counts[max(SPLITS, key=lambda k: counts[k])] -= 1
    return counts


def assign_splits(n_cases: int, fractions: dict) -> list[str]:
    """Split of each of n_cases ordered cases, spread evenly along the order.

    The smaller splits sit at evenly spaced positions (valid at 1/3, test at 2/3 of each period,
    so they interleave), the largest split fills the rest: for 0.8/0.1/0.1 every 10 consecutive
    cases hold 8 train, 1 valid, 1 test. Split sizes equal split_counts exactly.
    """
    counts = split_counts(n_cases, fractions)
    fill = max(SPLITS, key=lambda s: counts[s])
    placed = [s for s in SPLITS if s != fill and counts[s] > 0]
    out: list[str | None] = [None] * n_cases
    for i, split in enumerate(placed):
        phase = (i + 1) / (len(placed) + 1)
        for j in range(counts[split]):
            ideal = int((j + phase) * n_cases / counts[split])
            # nearest free position (a collision with another split's position moves it by one)
            free = min((k for k in range(n_cases) if out[k] is None), key=lambda k: (abs(k - ideal), k))
            out[free] = split
    return [fill if s is None else s for s in out]


def sample_dataset(name: str, spec: dict) -> list[dict]:
    """Rows of one dataset (validated config section `spec`), ordered by case_id."""
    rng = np.random.default_rng(spec.get("seed", 0))
    n_cases = spec["n_cases"]
    levels = {k: spec[k]["values"] for k in VARIED if isinstance(spec.get(k), dict) and "values" in spec[k]}
    ranges = {k: spec[k]["range"] for k in VARIED if isinstance(spec.get(k), dict) and "range" in spec[k]}
    fixed = {k: spec[k] for k in VARIED + FIXED if k in spec and not isinstance(spec[k], dict)}

    combos = list(itertools.product(*levels.values()))
    per_combo = np.full(len(combos), n_cases // len(combos))
    per_combo[rng.permutation(len(combos))[: n_cases % len(combos)]] += 1

    samples = []
    for combo, m in zip(combos, per_combo):
        if m == 0:
            continue
        # Latin hypercube: one sample in each of m equal strata of every range, strata shuffled
        lhs = {k: lo + (rng.permutation(m) + rng.uniform(size=m)) / m * (hi - lo) for k, (lo, hi) in ranges.items()}
        group = [dict(zip(levels, combo), **{k: float(v[i]) for k, v in lhs.items()}) for i in range(m)]
        group.sort(key=lambda row: tuple(row[k] for k in ranges))
        samples += group

    splits = assign_splits(n_cases, spec["splits"])
    case_seeds = rng.integers(0, 2**31 - 1, size=n_cases)
    overrides = {int(k.split("_")[1]): v for k, v in spec.get("overrides", {}).items()}
    rows = []
    for index, (varied, split) in enumerate(zip(samples, splits)):
        case_id = case_id_of(index, n_cases)
        row = {
            "dataset": name,
            "case_id": case_id,
            "split": split,
            "material": spec["material"],
            "output_interval": spec["output_interval"],
            "seed": int(case_seeds[index]),
        }
        row.update(fixed)
        row.update({k: float(f"{float(v):.{SIGNIFICANT_DIGITS}g}") for k, v in varied.items()})
        row.update(overrides.get(index, {}))
        rows.append(row)
    return rows


def case_table(config: dict) -> dict[str, dict]:
    """{"<dataset>/<case_id>": row} for every case of every dataset in the validated `config`.

    Every row is checked by building its CollapseCase; a bad case raises ConfigError naming the
    dataset, the case and the field.
    """
    table = {}
    for name in sorted(config["datasets"]):
        for row in sample_dataset(name, config["datasets"][name]):
            key = f"{name}/{row['case_id']}"
            try:
                case_from_row(row)
            except CaseError as exc:
                varied = {k: row[k] for k in VARIED if k in row}
                raise ConfigError(
                    f"datasets.{name}: case {row['case_id']} {varied} is not a valid DEM case: {exc}"
                ) from exc
            table[key] = row
    return table


def case_from_row(row: dict) -> CollapseCase:
    """The CollapseCase of a case-table row (bookkeeping columns dropped)."""
    fields = {k: v for k, v in row.items() if k not in ("dataset", "case_id", "split")}
    return CollapseCase.from_dict(dict(fields, name=f"{row['dataset']}/{row['case_id']}"))


# --- deck: the engine-neutral description of one case ------------------------------------------
def write_deck(row: dict, path: str | os.PathLike, case: CollapseCase | None = None) -> CollapseCase:
    """Write the case's deck JSON {"row": row, "case": CollapseCase.to_dict()} atomically; case:
    the row's case where the row alone does not give it (None: case_from_row(row))."""
    case = case_from_row(row) if case is None else case
    write_text(path, json.dumps({"row": row, "case": case.to_dict()}, indent=1, sort_keys=True) + "\n")
    return case


def read_deck(path: str | os.PathLike) -> tuple[CollapseCase, dict]:
    """(CollapseCase, case-table row) from a deck written by write_deck."""
    try:
        deck = json.loads(Path(path).read_text())
        return CollapseCase.from_dict(deck["case"]), deck["row"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CaseError(f"{path}: not a valid case deck ({exc})") from exc


def write_case_table(rows: Iterable[dict], path: str | os.PathLike) -> None:
    """The case table as CSV (one row per case, columns in first-seen order), atomically."""
    rows = list(rows)
    columns = list(dict.fromkeys(k for row in rows for k in row))
    lines = [",".join(columns)] + [
        ",".join("" if row.get(c) is None else str(row.get(c, "")) for c in columns) for row in rows
    ]
    write_text(path, "\n".join(lines) + "\n")
