"""Config validation across keys (pipeline/config.py): a key naming a dataset, a `measured` entry
or a GNS that is not there fails with a ConfigError naming the key, before any job runs.

The schema checks themselves are tested in test_grid.py (and the runout section in test_runout.py).
"""

import re
import warnings
from pathlib import Path

import pytest
import yaml

import dem.grid
import pipeline.config
from dem.grid import case_table
from pipeline.config import ConfigError, check_cross_keys, check_doe, check_gns, validate_config

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"


@pytest.fixture(autouse=True)
def in_repository(monkeypatch):
    """Measured CSV paths in the configs are relative to the workflow's root, as under Snakemake."""
    monkeypatch.chdir(ROOT)


def validated(name="config.yaml", edit=None):
    config = yaml.safe_load((ROOT / "config" / name).read_text())
    if edit:
        edit(config)
    return validate_config(config, SCHEMA)


def cross_key_error(config) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a GeometryWarning on the way is not what these tests look at
        with pytest.raises(ConfigError) as info:
            check_cross_keys(config, case_table(config))
    return str(info.value)


def test_one_config_error_class():
    assert pipeline.config.ConfigError is dem.grid.ConfigError


@pytest.mark.parametrize(
    "name, expected",
    [("config.yaml", {"quartz": "quartz_multiple"}), ("paper.yaml", {"quartz": "quartz_multiple"}), ("test.yaml", {})],
)
def test_shipped_configs_pass_and_give_each_inverse_column_its_gns_dataset(name, expected):
    config = validated(name)
    assert check_cross_keys(config, case_table(config)) == expected


@pytest.mark.parametrize("key", ["datasets", "per_dataset"])
def test_gns_key_naming_an_unknown_dataset(key):
    value = ["nope"] if key == "datasets" else {"nope": {"steps": 5}}
    config = validated("test.yaml", lambda c: c["gns"].update({key: value}))
    message = f"config key gns.{key}: 'nope' is not a dataset (datasets: ['tiny_friction', 'tiny_multiple'])"
    with pytest.raises(ConfigError, match=re.escape(message)):
        check_gns(config)
    assert message in cross_key_error(config)


def test_doe_measured_not_an_entry_of_measured():
    config = validated(edit=lambda c: c["doe"].update(measured=["quartz", "sand"]))
    message = "config key doe.measured: 'sand' is not an entry of `measured` (entries: ['copper', 'quartz'])"
    with pytest.raises(ConfigError, match=re.escape(message)):
        check_doe(config)
    assert message in cross_key_error(config)


def test_dataset_named_like_a_doe_of_measured():
    def edit(config):
        config["datasets"]["doe_quartz"] = config["datasets"]["quartz_multiple"]

    config = validated(edit=edit)
    message = "config key datasets.doe_quartz: the name is taken by the DoE of measured 'quartz'"
    assert message in cross_key_error(config)


def test_inverse_measured_not_an_entry_of_measured():
    config = validated(edit=lambda c: c["inverse"].update(measured=["sand"]))
    assert (
        "config key inverse.measured: 'sand' is not an entry of `measured` (entries: ['copper', 'quartz'])"
        in cross_key_error(config)
    )


def test_inverse_dataset_without_a_gns():
    config = validated(edit=lambda c: c["inverse"].update(dataset={"quartz": "quartz_friction"}))
    assert (
        "config key inverse.dataset.quartz: 'quartz_friction' has no GNS (gns datasets: ['quartz_multiple'])"
        in cross_key_error(config)
    )


def test_inverse_column_outside_the_geometry_of_its_gns():
    def edit(config):
        config["gns"]["datasets"] = ["quartz_friction", "quartz_multiple"]
        config["inverse"]["dataset"] = {"quartz": "quartz_friction"}  # a = 1, 2; the measured column has a = 6

    message = cross_key_error(validated(edit=edit))
    assert (
        "config key inverse.measured: 'quartz' cannot be calibrated with the GNS of dataset 'quartz_friction'"
        in message
    )
    assert "aspect_ratio = 6 lies outside [1, 2]" in message


def test_inverse_column_of_a_material_no_gns_was_trained_on():
    config = validated(edit=lambda c: c["inverse"].update(measured=["quartz", "copper"]))
    message = cross_key_error(config)
    assert "config key inverse.measured: 'copper' has no GNS dataset to calibrate it" in message
    assert "copper" in message and "quartz_multiple" in message


def test_inverse_recovery_dataset_without_a_gns():
    config = validated(edit=lambda c: c["inverse"].update(recovery_datasets=["quartz_friction"]))
    assert (
        "config key inverse.recovery_datasets: 'quartz_friction' has no GNS (gns datasets: ['quartz_multiple'])"
        in cross_key_error(config)
    )


def test_checks_run_in_stage_order():
    """Several bad keys: the GNS's is reported first (the stage the others build on)."""

    def edit(config):
        config["gns"]["datasets"] = ["nope"]
        config["doe"]["measured"] = ["sand"]
        config["inverse"]["recovery_datasets"] = ["quartz_friction"]

    assert cross_key_error(validated(edit=edit)).startswith("config key gns.datasets: 'nope'")


@pytest.mark.parametrize(
    "where, old, new",
    [
        ("dataset", "column_length", "L_i"),
        ("dataset", "wall_friction", "friction_wall"),
        ("override", "base_friction", "friction_base"),
    ],
)
def test_old_case_key_names_its_new_name(where, old, new):
    """One name per quantity (README "Renamed keys"): a config written for the old names fails at the key."""

    def edit(config):
        spec = config["datasets"]["tiny_friction"]
        if where == "dataset":
            spec[old] = spec.pop("L_i") if old == "column_length" else 0.5
        else:
            spec["overrides"] = {"case_000": {old: 0.5}}

    with pytest.raises(ConfigError) as info:
        validated("test.yaml", edit)
    prefix = "datasets.tiny_friction." + ("overrides.case_000." if where == "override" else "")
    assert f"{prefix}{old}: renamed to {new}" in str(info.value)


def test_old_checkpoint_key_names_its_new_name():
    from gns.simulator import CheckpointError, SimulatorConfig

    with pytest.raises(CheckpointError, match="connectivity_radius is now connectivity_radius_m"):
        SimulatorConfig.from_dict({"connectivity_radius": 0.004})
