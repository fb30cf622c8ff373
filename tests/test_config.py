"""Config validation across keys (pipeline/config.py): a key naming a dataset, a `measured` entry
or a GNS that is not there fails with a ConfigError naming the key, before any job runs.

The schema checks themselves are tested in test_grid.py (and the runout section in test_runout.py).
"""

import json
import re
import warnings
from pathlib import Path

import pytest
import yaml

import dem.grid
import pipeline.cases
import pipeline.config
import pipeline.dem
from calibration.calibrated import model_dataset_cases, model_record
from calibration.mechanisms import get_mechanisms
from calibration.model import Model
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


def test_inverse_bounds_outside_the_range_the_gns_is_trained_on():
    """The GNS's trained range is its dataset's cases' span, known from the case table before any job."""
    config = validated(edit=lambda c: c["inverse"].update(friction=[0.2, 0.9]))
    message = "config key inverse.friction: bounds [0.2, 0.9] leave the range the GNS of dataset 'quartz_multiple'"
    assert message in cross_key_error(config) and "the GNS would extrapolate" in cross_key_error(config)
    inside = validated(edit=lambda c: c["inverse"].update(restitution=[0.4, 0.8]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert check_cross_keys(inside, case_table(inside))["quartz"] == "quartz_multiple"


def test_dataset_named_like_a_calibrated_models_gns_dataset():
    def edit(config):
        config["datasets"]["calibrated_copper"] = config["datasets"]["quartz_multiple"]

    message = "config key datasets.calibrated_copper: the name is taken by the GNS dataset of the calibrated model"
    assert message in cross_key_error(validated(edit=edit))


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
    """One name per quantity (docs/dem.md, "Renamed keys"): a config written for the old names fails at the key."""

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


# --- the size guard (dem.min_grains_across, dem.case.check_grains_across) ------------------------
GUARD = "under the minimum of 8 (dem.min_grains_across)"


def test_grains_across_is_the_column_length_in_simulated_grains():
    from dem.case import CollapseCase

    case = CollapseCase("quartz", 0.01, 2.0, 0.5, 0.6, size_scale=5)
    assert case.grains_across == pytest.approx(0.01 / (425e-6 * 5))  # 4.7: the diagnosis' default at L_i = 0.01 m


def test_dataset_too_few_grains_across_names_the_dataset_the_cases_and_the_largest_passing_scale():
    """tiny_friction: L_i = 0.01 m of quartz at size_scale 4 is 5.9 grains across; 0.01/(8 x 425 um) = 2.94."""

    def at(size_scale):
        def edit(config):
            del config["dem"]["min_grains_across"]  # the default, 8
            config["datasets"]["tiny_friction"]["size_scale"] = size_scale
            config["datasets"]["tiny_multiple"]["size_scale"] = 2  # copper 0.01 m: 15 across

        return validated("test.yaml", edit)

    message = cross_key_error(at(4))
    assert message.startswith(
        "config key datasets.tiny_friction, case case_000 (cases under the minimum: case_000, case_001, case_002, "
        "case_003, case_004): L_i = 0.01 m at size_scale 4 is 5.88 quartz grains across"
    )
    assert GUARD in message and "Largest size_scale that passes: 2.94;" in message
    assert "L_i >= 0.0136 m at size_scale 4" in message  # 8 x 4 x 425 um
    config = at(2.94)  # the largest passing scale does pass, one step above it does not
    assert check_cross_keys(config, case_table(config)) == {}
    assert "datasets.tiny_friction" in cross_key_error(at(2.95))


def test_dataset_range_names_only_the_cases_under_the_minimum():
    """The paper's L_i range [0.01, 0.02] m over 20 cases at size_scale 3: only the shortest case is under 8."""
    config = validated(edit=lambda c: c["datasets"]["quartz_friction"].update(L_i={"range": [0.01, 0.02]}, n_cases=20))
    short = [row for row in case_table(config).values() if row["dataset"] == "quartz_friction" and row["L_i"] < 0.0102]
    assert [row["case_id"] for row in short] == ["case_000"]
    message = cross_key_error(config)
    assert message.startswith(
        f"config key datasets.quartz_friction, case case_000: L_i = {short[0]['L_i']:g} m at size_scale 3 is "
    )
    assert GUARD in message and "Largest size_scale that passes: 2.94;" in message


def test_a_lower_minimum_from_the_config_is_applied():
    config = validated(edit=lambda c: c["datasets"]["quartz_friction"].update(L_i={"range": [0.01, 0.02]}))
    config["dem"]["min_grains_across"] = 7.5
    assert check_cross_keys(config, case_table(config)) == {"quartz": "quartz_multiple"}
    with pytest.raises(ConfigError, match=re.escape("dem.min_grains_across: 1 is out of range; allowed: >= 2")):
        validated(edit=lambda c: c["dem"].update(min_grains_across=1))


def short_quartz_csv(tmp_path) -> str:
    """The shipped quartz curve as a column of L_i = 0.01 m (a = 6)."""
    text = (ROOT / "data" / "measured" / "quartz_a6.csv").read_text()
    assert text.count("quartz_a6,quartz,6.0,0.02,") >= 2
    path = tmp_path / "short.csv"
    path.write_text(text.replace("quartz_a6,quartz,6.0,0.02,", "short_a6,quartz,6.0,0.01,"))
    return str(path)


def test_diagnosis_of_a_column_too_few_grains_across_at_its_size_scale(tmp_path):
    """The issue's case: diagnosis.size_scale 5 at L_i = 0.01 m of quartz is 4.7 grains across."""
    short = short_quartz_csv(tmp_path)
    config = validated(edit=lambda c: c["measured"].update(short=short))
    message = cross_key_error(config)
    assert message.startswith(
        f"config key diagnosis.size_scale (measured 'short': {short}, line 8, column 'L_i' of measured column "
        "'short_a6'): L_i = 0.01 m at size_scale 5 "
        "is 4.71 quartz grains across"
    )
    assert GUARD in message and "Largest size_scale that passes: 2.94;" in message
    config["diagnosis"]["size_scale"] = 2.94
    config["calibration"].update(target_size_scale=2.5, finer_size_scale=2)  # not coarser than the calibration
    assert check_cross_keys(config, case_table(config)) == {"quartz": "quartz_multiple"}
    config["diagnosis"].update(size_scale=5, enabled=False)  # no diagnosis, no diagnosis runs to guard
    config["calibration"]["model"] = "base"  # (auto would need the diagnosis)
    assert check_cross_keys(config, case_table(config)) == {"quartz": "quartz_multiple"}


def test_a_target_scale_coarser_than_the_calibration_or_no_coarser_than_its_transfer_is_refused(tmp_path):
    """calibration.target_size_scale above the calibration's (diagnosis.size_scale 5), a
    finer_size_scale not below the target's (or, with no target, the calibration's), and a target
    the size guard refuses (the calibration's guard off with the diagnosis) are named by key."""
    message = "config key calibration.target_size_scale: 6 is coarser than the calibration's size_scale 5"
    assert cross_key_error(validated(edit=lambda c: c["calibration"].update(target_size_scale=6))).startswith(message)
    config = validated(edit=lambda c: c["calibration"].update(finer_size_scale=3))
    message = (
        "config key calibration.finer_size_scale: 3 is not finer than the target's (calibration.target_size_scale) 3"
    )
    assert cross_key_error(config).startswith(message)
    config["calibration"].update(target_size_scale=None, finer_size_scale=5)
    assert cross_key_error(config).startswith(
        "config key calibration.finer_size_scale: 5 is not finer than the calibration's 5"
    )
    config["calibration"].update(target_size_scale=5, finer_size_scale=None)  # the calibration's own: no target
    check_cross_keys(config, case_table(config))
    short = short_quartz_csv(tmp_path)  # L_i = 0.01 m: 7.84 grains across at size_scale 3
    config["measured"]["short"] = short
    config["diagnosis"]["enabled"], config["calibration"]["model"] = False, "base"
    config["calibration"]["target_size_scale"] = 3
    message = cross_key_error(config)
    assert message.startswith(
        "config key calibration.target_size_scale (measured 'short', column 'short_a6'): L_i = 0.01 m"
    )
    assert GUARD in message


def test_a_plausible_range_of_an_unknown_mechanism_upside_down_or_outside_its_bounds_is_refused():
    """calibration.plausible_ranges: each entry names a candidate mechanism and an interval that
    meets the bounds the calibration searches; the error names the key down to the mechanism."""
    stated = {"range": [0.05, 0.25], "source": "shear-box tests of this sand on the channel's acrylic"}
    ranges = {"quartz": {"sidewall_friction": stated}}
    config = validated(edit=lambda c: c["calibration"].update(plausible_ranges=ranges))
    check_cross_keys(config, case_table(config))
    for mechanism, low_high, says in (
        ("wall_friction", [0.1, 0.2], "'wall_friction' is not a candidate mechanism"),
        ("sidewall_friction", [0.25, 0.05], "plausible range [0.25, 0.05] is not an interval"),
        ("cohesion", [70.0, 90.0], "plausible range [70, 90] lies outside the bond_number bounds [0, 60]"),
    ):
        entry = {"quartz": {mechanism: dict(stated, range=low_high)}}
        config = validated(edit=lambda c, entry=entry: c["calibration"].update(plausible_ranges=entry))
        message = cross_key_error(config)
        assert message.startswith(f"config key calibration.plausible_ranges.quartz.{mechanism}: "), message
        assert says in message, message
    with pytest.raises(ConfigError, match="source"):  # a range needs its source
        validated(edit=lambda c: c["calibration"].update(plausible_ranges={"quartz": {"cohesion": {"range": [0, 1]}}}))


def test_doe_column_too_few_grains_across_at_doe_size_scale():
    """The measured quartz column (L_i = 0.02 m) at doe.size_scale 6 is 7.8 across; 0.02/(8 x 425 um) = 5.88."""
    config = validated(edit=lambda c: c["doe"].update(size_scale=6))
    message = "config key doe.size_scale (measured 'quartz'): L_i = 0.02 m at size_scale 6 is 7.84 quartz grains across"
    with pytest.raises(ConfigError, match=re.escape(message)):
        check_doe(config)
    assert cross_key_error(config).startswith(message)
    assert "Largest size_scale that passes: 5.88;" in cross_key_error(config)
    config["doe"]["size_scale"] = 5.88
    check_doe(config)


def test_scale_ladder_guarded_at_its_coarsest_scale_named_apart_and_its_runs_cases():
    """The default ladder (size_scale 5, 4, 3 of the quartz column) passes; size_scale 6 is 7.8 across
    and refused, naming the key; a dataset named scale_ladder and a material that is none are refused."""
    config = validated()
    assert config["scale_ladder"]["size_scales"] == [5, 4, 3] and config["scale_ladder"]["friction"] == 0.39
    pipeline.config.check_scale_ladder(config)
    config["scale_ladder"]["size_scales"] = [6, 1]
    assert cross_key_error(config).startswith("config key scale_ladder.size_scales (6): L_i = 0.02 m at size_scale 6")
    config["scale_ladder"]["size_scales"] = [5]
    config["datasets"]["scale_ladder"] = config["datasets"]["quartz_multiple"]
    assert "config key datasets.scale_ladder: the name is taken by the runs of scale_ladder" in cross_key_error(config)
    with pytest.raises(ConfigError, match="scale_ladder: not a valid DEM case: .*sand"):
        validated(edit=lambda c: c["scale_ladder"].update(material="sand"))
    assert validated("test.yaml")["scale_ladder"]["size_scales"] == []  # off unless a config asks


# -- your own column (README "Calibrate your own column"): pipeline.config.derive_columns ----------------
GLASS = {"name": "glass", "diameter": 0.0004, "density": 2500.0, "solid_fraction": 0.6}


def own_csv(tmp_path, material="glass", a=3.0, L_i=0.02, own=",0.0004,2500,0.6", name="mine.csv") -> str:
    """The shipped quartz curve's runout as a column of `material`, a, L_i, with the cells `own`."""
    rows = [r for r in (ROOT / "data/measured/quartz_a6.csv").read_text().splitlines() if ",runout," in r]
    header = "column,material,aspect_ratio,L_i,kind,x,value,std,grain_diameter,density,solid_fraction"
    lines = [header] + [f"mine,{material},{a},{L_i},runout,{r.split(',')[5]},{r.split(',')[6]},{own}" for r in rows]
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def derived(config, added=("mine",)):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return pipeline.config.derive_columns(config, added)


def test_shipped_configs_need_nothing_derived_but_the_tiny_datasets_column():
    for name in ("config.yaml", "paper.yaml", "test.yaml"):
        config = validated(name)
        assert derived(config, ()) == config, name
    tiny = derived(validated("tiny_all.yaml"), ())  # its dataset follows its CSV (`measured: tiny`)
    spec = tiny["datasets"]["tiny_column"]
    assert (spec["material"], spec["aspect_ratio"], spec["L_i"]) == ("quartz", 2.0, 0.01)
    assert check_cross_keys(tiny, case_table(tiny)) == {"tiny": "tiny_column"}


def test_a_column_added_on_the_command_line_gets_a_gns_dataset_of_its_own_material_and_geometry(tmp_path):
    """--config measured='{mine: glass.csv}' on the default config: a dataset like quartz_multiple (the
    GNS dataset of the config's inverse column) of the CSV's material, a and L_i, its GNS, the inverse design."""
    config = derived(validated(edit=lambda c: c["measured"].update(mine=own_csv(tmp_path))))
    spec, template = config["datasets"]["inverse_mine"], config["datasets"]["quartz_multiple"]
    assert spec["material"] == GLASS and (spec["aspect_ratio"], spec["L_i"], spec["measured"]) == (3.0, 0.02, "mine")
    for key in ("n_cases", "seed", "friction", "restitution", "splits", "size_scale", "duration_over_tstar"):
        assert spec.get(key) == template.get(key), key
    assert spec["output_interval"] == 0.00354  # 0.005 s x sqrt(H_i 0.06 / 0.12 m): as many frames per t*
    assert config["inverse"]["measured"] == ["quartz", "mine"] and config["doe"]["measured"] == ["quartz"]
    assert config["gns"]["datasets"] == ["quartz_multiple", "inverse_mine"]
    assert check_cross_keys(config, case_table(config)) == {"quartz": "quartz_multiple", "mine": "inverse_mine"}
    assert derived(config) == config  # deterministic, and derived once


def test_a_derived_dataset_takes_the_largest_size_scale_the_size_guard_lets_its_column_take(tmp_path):
    config = validated("tiny_all.yaml", lambda c: c["measured"].update(mine=own_csv(tmp_path, a=2.0, L_i=0.008)))
    config = derived(config)
    assert config["datasets"]["inverse_mine"]["size_scale"] == 4.0  # 0.008 / (5 x 0.4 mm) = 4 across the minimum
    config = derived(validated("tiny_all.yaml", lambda c: c["measured"].update(mine=own_csv(tmp_path, L_i=0.006))))
    assert config["datasets"]["inverse_mine"]["size_scale"] == 3.0


def test_a_column_added_that_a_gns_dataset_holds_is_calibrated_by_it(tmp_path):
    csv = own_csv(tmp_path, material="quartz", a=6.0, own=",,,")
    config = derived(validated(edit=lambda c: c["measured"].update(mine=csv)))
    assert "inverse_mine" not in config["datasets"] and config["inverse"]["measured"] == ["quartz", "mine"]
    assert check_cross_keys(config, case_table(config)) == {"quartz": "quartz_multiple", "mine": "quartz_multiple"}


def test_an_entry_of_the_config_file_keeps_the_routes_the_file_gives_it(tmp_path):
    config = validated(edit=lambda c: c["measured"].update(mine=own_csv(tmp_path)))
    assert derived(config, ()) == config  # not added on the command line: diagnosis and calibrated model only


@pytest.mark.parametrize(
    "edit, message",
    [
        (  # a measured CSV that breaks the schema: the key, the file, the line and the CSV column
            lambda c, p: c["measured"].update(mine=own_csv(p, own=",0.0004,,0.6")),
            r"config key measured.mine: .*mine.csv, line 2, column 'material': unknown material 'glass'.*"
            r"missing: \['density'\]",
        ),
        (
            lambda c, p: c["measured"].update(mine=own_csv(p, L_i=20)),
            r"config key measured.mine: .*mine.csv, line 2, column 'L_i': 20.0 is not a column length in metres",
        ),
        (  # one name, two materials
            lambda c, p: c["measured"].update(mine=own_csv(p), other=own_csv(p, own=",0.0004,2400,0.6", name="o.csv")),
            r"config key measured.other \(.*o.csv\): material 'glass' is .*density=2400.*, but measured.mine",
        ),
    ],
)
def test_bad_measured_input_fails_at_parse_time_naming_the_key_and_file(tmp_path, edit, message):
    config = validated(edit=lambda c: edit(c, tmp_path))
    with pytest.raises(ConfigError, match=message):
        derived(config)


WHERE = "datasets.quartz_multiple"


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"material": "glass"}, rf"{WHERE}.material: unknown material 'glass'; known: \['copper', 'quartz'\]"),
        (
            {"material": {"name": "glass", "diameter": 4e-4, "density": 2500}},
            rf"{WHERE}.material: 'solid_fraction' is a required property",
        ),
        ({"material": dict(GLASS, name="quartz")}, rf"{WHERE}.material: 'quartz' is a material of the table"),
        ({"measured": "sand"}, rf"{WHERE}: measured 'sand' gives the column; leave out \['material', 'aspect_ratio'"),
        (
            {"measured": "sand", "material": None, "aspect_ratio": None, "L_i": None},
            rf"{WHERE}.measured: 'sand' is not an entry of `measured`",
        ),
        ({"L_i": None}, rf"{WHERE}: \['L_i'\] missing; give \['material', 'aspect_ratio', 'L_i'\], or `measured"),
    ],
)
def test_a_dataset_material_or_column_that_is_not_one_is_refused_naming_the_key(spec, message):
    def edit(config):
        dataset = config["datasets"]["quartz_multiple"]
        dataset.update(spec)
        for key in [k for k, v in spec.items() if v is None]:
            del dataset[key]

    with pytest.raises(ConfigError, match=message):
        validated(edit=edit)


def test_one_case_table_holds_every_dem_run_of_the_dag():
    """pipeline.cases.case_table: the datasets' cases, the DoE's design runs, the scale ladder and
    the calibrated model's GNS dataset, each under its own dataset, every key once; no rule file
    adds to it after common.smk built it."""
    tiny = derived(validated("tiny_all.yaml"), ())
    table = pipeline.cases.case_table(tiny, {"tiny": "tiny_column"})
    by_dataset = {}
    for key, row in table.items():
        assert key == f"{row['dataset']}/{row['case_id']}"
        by_dataset.setdefault(row["dataset"], []).append(row)
    # 5 dataset cases, a 3 x 3 factorial + 1 centre replicate, 1 ladder run, config gns_cases 3
    assert {d: len(rows) for d, rows in by_dataset.items()} == {
        "tiny_column": 5,
        "doe_tiny": 10,
        "scale_ladder": 1,
        "calibrated_tiny": 3,
    }
    assert table == {**case_table(tiny), **{k: v for k, v in table.items() if not k.startswith("tiny_column/")}}
    doe = by_dataset["doe_tiny"]
    levels = (0.3, 0.6, 0.9)
    assert {(r["friction"], r["restitution"]) for r in doe} == {(m, e) for m in levels for e in levels}
    assert all(r["size_scale"] == 4 and r["L_i"] == 0.01 and r["aspect_ratio"] == 2.0 for r in doe)
    assert by_dataset["scale_ladder"][0]["case_id"] == "scale4_packing0"
    # the calibrated model's cases: ids, splits and what gives their parameters once model.json is written
    model_rows = by_dataset["calibrated_tiny"]
    assert sorted(r["split"] for r in model_rows) == ["test", "train", "valid"]
    assert all(r["calibrated"] == "tiny" and "friction" not in r for r in model_rows)
    assert all(r["template"] == by_dataset["tiny_column"][0] for r in model_rows)
    # off with the base model: no GNS route of a model, no dataset for it
    base = dict(tiny, calibration=dict(tiny["calibration"], model="base"))
    assert not [k for k in pipeline.cases.case_table(base, {"tiny": "tiny_column"}) if k.startswith("calibrated_")]
    for rules in (ROOT / "workflow" / "rules").glob("*.smk"):
        text = rules.read_text()
        assert not re.search(r"\bCASES\s*(\[[^\]]*\]\s*=|\.update|\.setdefault)", text), rules.name


def test_a_calibrated_models_deck_is_a_case_of_its_model_json(tmp_path):
    """dem_deck on a calibrated model's row: the case of the model's design at that case id (the
    template's column, the model's parameters there), which the deck's row records; without its
    model.json the row is refused."""
    tiny = derived(validated("tiny_all.yaml"), ())
    rows = pipeline.cases.dataset_rows(pipeline.cases.case_table(tiny, {"tiny": "tiny_column"}), "calibrated_tiny")
    with pytest.raises(ValueError, match="needs its model.json"):
        pipeline.dem.write_deck(rows[1], tmp_path / "refused.json")
    model = Model(get_mechanisms(["cohesion"], tiny["diagnosis"]["channel_width"])[0])
    model_json = tmp_path / "model.json"
    model_json.write_text(json.dumps(model_record(model, "test", "tiny")))
    case = pipeline.dem.write_deck(rows[1], tmp_path / "deck.json", model_json)
    read_case, row = dem.grid.read_deck(tmp_path / "deck.json")
    section = tiny["calibration"]
    design = model_dataset_cases(
        model, dem.grid.case_from_row(rows[1]["template"]), section["gns_cases"], section["seed"]
    )
    assert read_case == case == design[1].case
    assert row["parameters"] == design[1].parameters and set(row["parameters"]) == set(model.parameter_names)
    assert (case.L_i, case.aspect_ratio) == (0.01, 2.0) and case.friction == row["parameters"]["friction"]


def test_one_gns_for_both_models_does_not_start_from_the_base_gns():
    """calibration.gns_shared replaces the base model's GNS that calibration.gns_warm_start starts
    from: both at once are refused, naming the keys."""
    config = validated(edit=lambda c: c["calibration"].update(gns_shared=True, gns_warm_start=True))
    assert cross_key_error(config).startswith(
        "config key calibration.gns_shared: one GNS for both models replaces the base model's GNS, but "
        "calibration.gns_warm_start starts the model's GNS from it"
    )
