"""The case table: config validation, expansion into cases, balanced splits, decks."""

import copy
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml

from dem.case import CollapseCase
from dem.grid import (
    ConfigError,
    assign_splits,
    case_from_row,
    case_table,
    read_deck,
    sample_dataset,
    split_counts,
    write_case_table,
    write_deck,
)
from pipeline.config import validate_config

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"


def load(name):
    return yaml.safe_load((ROOT / "config" / name).read_text())


@pytest.fixture(scope="module")
def paper_table():
    return case_table(validate_config(load("paper.yaml"), SCHEMA))


@pytest.mark.parametrize("name", ["config.yaml", "paper.yaml", "test.yaml"])
def test_shipped_configs_validate_and_fill_defaults(name):
    config = validate_config(load(name), SCHEMA)
    assert config["dem"]["engine"] in ("auto", "builtin")
    for spec in config["datasets"].values():
        assert set(spec["splits"]) == {"train", "valid", "test"}
        assert spec["overrides"] == {} or all(k.startswith("case_") for k in spec["overrides"])
    assert len(case_table(config)) == sum(spec["n_cases"] for spec in config["datasets"].values())


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda c: c["dem"].update(enigne="builtin"), ["dem.enigne", "unknown key", "engine", "threads"]),
        (lambda c: c.update(extra_section={}), ["extra_section", "unknown key", "datasets", "gns"]),
        (lambda c: c["dem"].update(engine="lammps"), ["dem.engine", "'lammps'", "auto", "builtin", "liggghts", "mfix"]),
        (
            lambda c: c["datasets"]["tiny_friction"].update(n_cases="five"),
            ["tiny_friction.n_cases", "wrong type", "integer"],
        ),
        (
            lambda c: c["datasets"]["tiny_friction"].update(restitution=1.5),
            ["tiny_friction.restitution", "1.5", "<= 1"],
        ),
        (
            lambda c: c["datasets"]["tiny_friction"].update(friction={"range": [0.3, 3.0]}),
            ["tiny_friction.friction.range.1", "<= 2"],
        ),
        (
            lambda c: c["datasets"]["tiny_friction"].update(friction={"range": [0.9, 0.3]}),
            ["tiny_friction.friction.range", "min <= max"],
        ),
        (lambda c: c["datasets"]["tiny_friction"].update(material="sand"), ["material", "quartz", "copper"]),
        (
            lambda c: c["datasets"]["tiny_friction"].update(splits={"train": 0.9, "valid": 0.1, "test": 0.1}),
            ["tiny_friction.splits", "sum to 1"],
        ),
        (
            lambda c: c["datasets"]["tiny_friction"].update(overrides={"case_009": {"friction": 0.5}}),
            ["overrides.case_009", "no such case", "case_000..case_004"],
        ),
        (lambda c: c["datasets"]["tiny_friction"].pop("output_interval"), ["output_interval", "required"]),
        (
            lambda c: c["gns"].update(per_dataset={"tiny_friction": {"pushforward_fraction": 2}}),
            ["gns.per_dataset.tiny_friction", "pushforward_fraction", "<= 1"],
        ),
        (
            lambda c: c["gns"].update(per_dataset={"tiny_friction": {"latent": 8}}),
            ["gns.per_dataset.tiny_friction", "latent: unknown key", "latent_size"],
        ),
    ],
)
def test_bad_config_names_key_and_allowed_values(edit, words):
    config = load("test.yaml")
    edit(config)
    with pytest.raises(ConfigError) as info:
        validate_config(config, SCHEMA)
    for word in words:
        assert word in str(info.value), str(info.value)


def test_case_that_cannot_be_simulated_names_dataset_case_and_field():
    config = validate_config(load("test.yaml"), SCHEMA)
    config["datasets"]["tiny_friction"]["L_i"] = 0.3  # a 0.9 m column in a 0.35 m box
    with pytest.raises(ConfigError, match=r"datasets.tiny_friction: case case_000 .* does not fit"):
        case_table(config)


def test_paper_table_has_table2_datasets_with_8_1_1_splits(paper_table):
    per_dataset = Counter(row["dataset"] for row in paper_table.values())
    assert per_dataset == {"quartz_friction": 500, "copper_friction": 100, "quartz_multiple": 50, "copper_multiple": 50}
    for name, n in per_dataset.items():
        splits = Counter(row["split"] for row in paper_table.values() if row["dataset"] == name)
        assert splits == {"train": n * 8 // 10, "valid": n // 10, "test": n // 10}
    quartz = [row for row in paper_table.values() if row["dataset"] == "quartz_friction"]
    assert {row["aspect_ratio"] for row in quartz} == {0.5, 1, 2, 3, 4, 5, 6}
    assert all(
        row["restitution"] == 0.65 and 0.3 <= row["friction"] <= 0.9 and 0.01 <= row["L_i"] <= 0.02 for row in quartz
    )
    multiple = [row for row in paper_table.values() if row["dataset"] == "quartz_multiple"]
    assert {(row["aspect_ratio"], row["L_i"]) for row in multiple} == {(6, 0.02)}
    assert len({row["restitution"] for row in multiple}) == 50


def test_paper_splits_are_balanced_over_the_varied_parameters(paper_table):
    quartz = [row for row in paper_table.values() if row["dataset"] == "quartz_friction"]
    # every aspect ratio is in every split, with about 8/1/1 of its cases
    for a in (0.5, 1, 2, 3, 4, 5, 6):
        counts = Counter(row["split"] for row in quartz if row["aspect_ratio"] == a)
        total = sum(counts.values())
        assert total in (71, 72)
        assert abs(counts["valid"] - total / 10) <= 1.5 and abs(counts["test"] - total / 10) <= 1.5, counts
    # valid and test span each range, their means near the middle
    for key, (lo, hi) in (("friction", (0.3, 0.9)), ("L_i", (0.01, 0.02))):
        for split in ("valid", "test"):
            values = np.array([row[key] for row in quartz if row["split"] == split])
            assert values.min() < lo + 0.15 * (hi - lo) and values.max() > hi - 0.15 * (hi - lo), (key, split)
            assert abs(values.mean() - (lo + hi) / 2) < 0.1 * (hi - lo), (key, split)


def test_latin_hypercube_fills_every_stratum_of_each_level(paper_table):
    for a in (0.5, 6):
        rows = [r for r in paper_table.values() if r["dataset"] == "quartz_friction" and r["aspect_ratio"] == a]
        for key, (lo, hi) in (("friction", (0.3, 0.9)), ("L_i", (0.01, 0.02))):
            strata = np.floor((np.array([r[key] for r in rows]) - lo) / (hi - lo) * len(rows)).astype(int)
            assert sorted(strata) == list(range(len(rows))), key


def test_table_is_deterministic_and_seeded():
    config = validate_config(load("paper.yaml"), SCHEMA)
    first = sample_dataset("copper_multiple", config["datasets"]["copper_multiple"])
    assert first == sample_dataset("copper_multiple", copy.deepcopy(config["datasets"]["copper_multiple"]))
    reseeded = dict(config["datasets"]["copper_multiple"], seed=99)
    other = sample_dataset("copper_multiple", reseeded)
    assert [r["friction"] for r in first] != [r["friction"] for r in other]
    assert len({r["seed"] for r in first}) == len(first)  # each case packs differently


def test_override_changes_only_that_case():
    config = validate_config(load("test.yaml"), SCHEMA)
    before = case_table(config)
    config["datasets"]["tiny_friction"]["overrides"] = {"case_001": {"friction": 0.55, "restitution": 0.4}}
    after = case_table(config)
    changed = [key for key in before if before[key] != after[key]]
    assert changed == ["tiny_friction/case_001"]
    assert after["tiny_friction/case_001"]["friction"] == 0.55
    assert after["tiny_friction/case_001"]["restitution"] == 0.4


@pytest.mark.parametrize(
    "fractions",
    [
        {"train": 0.8, "valid": 0.1, "test": 0.1},
        {"train": 0.6, "valid": 0.2, "test": 0.2},
        {"train": 1.0, "valid": 0.0, "test": 0.0},
    ],
)
def test_assign_splits_matches_counts_and_spreads_them(fractions):
    for n in range(1, 60):
        if n < sum(1 for f in fractions.values() if f > 0):
            continue
        splits = assign_splits(n, fractions)
        counts = split_counts(n, fractions)
        assert Counter(splits) == {k: v for k, v in counts.items() if v}
        assert sum(counts.values()) == n
        assert all(counts[s] >= 1 for s in fractions if fractions[s] > 0)
        for split, count in counts.items():
            # evenly spread: consecutive cases of a split lie about n / count apart, never bunched
            where = [k for k, s in enumerate(splits) if s == split]
            assert all(0 < b - a <= -(-n // count) + 2 for a, b in zip(where, where[1:])), (n, split, splits)


def test_rows_become_cases_and_decks_round_trip(tmp_path):
    table = case_table(validate_config(load("test.yaml"), SCHEMA))
    row = table["tiny_multiple/case_002"]
    case = case_from_row(row)
    assert isinstance(case, CollapseCase)
    assert case.L_i == row["L_i"] and case.friction == row["friction"]
    assert case.material.name == "copper" and case.size_scale == 4 and case.output_interval == 0.002
    assert case.name == "tiny_multiple/case_002"
    deck = tmp_path / "deck.json"
    write_deck(row, deck)
    case_back, row_back = read_deck(deck)
    assert case_back == case and row_back == row
    write_case_table(table.values(), tmp_path / "cases.csv")
    lines = (tmp_path / "cases.csv").read_text().splitlines()
    assert lines[0].startswith("dataset,case_id,split,material") and len(lines) == len(table) + 1
