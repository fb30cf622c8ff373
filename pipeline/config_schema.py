"""The config's schema check (pipeline.config.validate_config): Snakemake's --config strings read as
the numbers, booleans and nulls the schema expects, workflow/schemas/config.schema.yaml checked with
every problem named by its key, the checks the schema cannot express (range order, split fractions,
overrides' case ids, each gns.per_dataset entry as the gns section it makes, the runout method),
and the defaults filled in. The checks across keys are pipeline/config.py's.
"""

from __future__ import annotations

import copy
import math
import os
from pathlib import Path

import jsonschema
import yaml

from dem.case import RENAMED_CASE_KEYS, CaseError, get_material
from dem.grid import SPLITS, VARIED, ConfigError, case_id_of
from dem.runout import RunoutError, RunoutMethod
from dem.scale_ladder import case_rows as ladder_rows

COLUMN_KEYS = ("material", "aspect_ratio", "L_i")  # a dataset's column, or `measured: <entry>` in their place


# --- the schema ----------------------------------------------------------------------------------
def validate_config(config: dict, schema_path: str | os.PathLike) -> dict:
    """Check `config` against the JSON schema at `schema_path` and fill its defaults.

    Returns a new dict, with the strings of the command line read (_read_command_line). Raises
    ConfigError listing every problem as `key.path: message`, with the allowed values (enum, bounds,
    known keys) in the message.
    """
    schema = yaml.safe_load(Path(schema_path).read_text())
    config = _read_command_line(copy.deepcopy(dict(config)), schema)
    renamed = _renamed_keys(config)
    if renamed:  # before the schema, whose "unexpected key" would not say what the key is now called
        raise ConfigError("invalid config:\n  " + "\n  ".join(renamed))
    validator = jsonschema.Draft202012Validator(schema)
    problems = [_describe(error, schema) for error in validator.iter_errors(config)]
    problems += _check_gns_per_dataset(config.get("gns", {}), schema)
    if problems:
        raise ConfigError("invalid config:\n  " + "\n  ".join(sorted(set(problems))))
    _fill_defaults(config, schema, schema)
    for name, spec in config.get("datasets", {}).items():
        problems += _check_dataset(name, spec, config.get("measured", {}))
    try:  # the schema checks each key; the class is the one definition every stage builds from it
        RunoutMethod.from_config(config.get("runout"))
    except RunoutError as exc:
        problems.append(str(exc))
    try:  # the ladder's runs are cases: each must be one (the material above all)
        ladder_rows(config["scale_ladder"])
    except CaseError as exc:
        problems.append(f"scale_ladder: not a valid DEM case: {exc}")
    if problems:
        raise ConfigError("invalid config:\n  " + "\n  ".join(problems))
    return config


# --- values given on the command line -------------------------------------------------------------
SCALAR_TYPES = ("integer", "number", "boolean", "null")  # schema types a command-line string may stand for


def _read_command_line(config: dict, schema: dict) -> dict:
    """`config` with every string YAML reads as a number, boolean or null read so where the schema
    expects one and no string (each gns.per_dataset entry by the gns section's schema).

    Snakemake reads a --config value with YAML's BaseLoader, which keeps every scalar inside it a
    string: `--config dem='{threads: 2}'` arrives as {"threads": "2"}, merged into the configfile's.
    """
    config = _read_strings(config, schema, schema)
    gns = config.get("gns")
    if isinstance(gns, dict) and isinstance(gns.get("per_dataset"), dict):
        section = schema["properties"]["gns"]
        gns["per_dataset"] = {name: _read_strings(o, section, schema) for name, o in gns["per_dataset"].items()}
    return config


def _read_strings(instance, schema: dict, root: dict):
    """`instance` with its strings read where `schema` (of the schema `root`) expects a scalar of
    SCALAR_TYPES and no string, recursing into objects and arrays; a new value."""
    schema = _resolve(schema, root)
    for part in schema.get("allOf", []):
        instance = _read_strings(instance, part, root)
    if isinstance(instance, str):
        types = schema.get("type", [])
        types = [types] if isinstance(types, str) else types
        return instance if "string" in types or not set(types) & set(SCALAR_TYPES) else _scalar(instance, types)
    if isinstance(instance, dict):
        properties, extra = schema.get("properties", {}), schema.get("additionalProperties")
        return {
            key: _read_strings(value, properties.get(key, extra if isinstance(extra, dict) else {}), root)
            for key, value in instance.items()
        }
    if isinstance(instance, list) and isinstance(schema.get("items"), dict):
        return [_read_strings(value, schema["items"], root) for value in instance]
    return instance


def _scalar(text: str, types: list[str]):
    """`text` read as YAML (a float also in Python's notation, 1e-3) when that gives a value of one of
    `types` (an integral number for an integer, a finite one for a number); else `text` itself."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(value, str):  # YAML 1.1 reads 1e-3 as a string
        try:
            value = float(text)
        except ValueError:
            return text
    if isinstance(value, bool):
        return value if "boolean" in types else text
    if value is None:
        return None if "null" in types else text
    if isinstance(value, int):
        return value if {"integer", "number"} & set(types) else text
    if isinstance(value, float) and math.isfinite(value):
        if "number" in types:
            return value
        if "integer" in types and value.is_integer():
            return int(value)
    return text


def _check_gns_per_dataset(gns: dict, schema: dict) -> list[str]:
    """Each gns.per_dataset entry checked as the gns section it makes for its dataset."""
    problems = []
    for name, override in (gns.get("per_dataset") or {}).items():
        where = f"gns.per_dataset.{name}"
        fixed = sorted(set(override) & {"datasets", "threads", "per_dataset"})
        if fixed:
            problems.append(f"{where}: {fixed} apply to the whole gns section, not to one dataset")
            continue
        section = {**{k: v for k, v in gns.items() if k != "per_dataset"}, **override}
        validator = jsonschema.Draft202012Validator(schema["properties"]["gns"])
        problems += [f"{where}: {_describe(error, schema)}" for error in validator.iter_errors(section)]
    return problems


def _describe(error, schema) -> str:
    key = ".".join(str(p) for p in error.absolute_path) or "(top level)"
    if error.validator == "additionalProperties":
        known = sorted(error.schema.get("properties", {}))
        extra = sorted(set(error.instance) - set(known)) if isinstance(error.instance, dict) else []
        where = f"{key}." if error.absolute_path else ""
        return f"{where}{', '.join(map(str, extra))}: unknown key; allowed keys here: {known}"
    if error.validator == "enum":
        return f"{key}: {error.instance!r} is not allowed; allowed values: {error.validator_value}"
    if error.validator in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        bounds = {
            k: error.schema[k]
            for k in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum")
            if k in error.schema
        }
        return f"{key}: {error.instance!r} is out of range; allowed: {_bounds_text(bounds)}"
    if error.validator == "type":
        return f"{key}: {error.instance!r} has the wrong type; expected {error.validator_value}"
    return f"{key}: {error.message}"


def _bounds_text(bounds: dict) -> str:
    low = (
        f"> {bounds['exclusiveMinimum']}"
        if "exclusiveMinimum" in bounds
        else f">= {bounds['minimum']}"
        if "minimum" in bounds
        else ""
    )
    high = (
        f"< {bounds['exclusiveMaximum']}"
        if "exclusiveMaximum" in bounds
        else f"<= {bounds['maximum']}"
        if "maximum" in bounds
        else ""
    )
    return " and ".join(b for b in (low, high) if b)


def _resolve(schema: dict, root: dict) -> dict:
    ref = schema.get("$ref")
    if ref:
        node = root
        for part in ref.lstrip("#/").split("/"):
            node = node[part]
        return node
    return schema


def _fill_defaults(instance, schema: dict, root: dict) -> None:
    """Fill `default` values of object properties in place (recursing into objects)."""
    schema = _resolve(schema, root)
    if not isinstance(instance, dict):
        return
    for key, sub in schema.get("properties", {}).items():
        sub = _resolve(sub, root)
        if key not in instance and "default" in sub:
            instance[key] = copy.deepcopy(sub["default"])
        if key in instance:
            _fill_defaults(instance[key], sub, root)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        for key, value in instance.items():
            if key not in schema.get("properties", {}):
                _fill_defaults(value, extra, root)


def _renamed_keys(config: dict) -> list[str]:
    """`key.path: renamed to NEW` for every key of an older version (docs/dem.md, "Renamed keys")."""
    problems = []
    for name, spec in (config.get("datasets") or {}).items():
        for old in sorted(set(spec or {}) & set(RENAMED_CASE_KEYS)):
            problems.append(f"datasets.{name}.{old}: renamed to {RENAMED_CASE_KEYS[old]}")
        for case_id, changes in ((spec or {}).get("overrides") or {}).items():
            for old in sorted(set(changes or {}) & set(RENAMED_CASE_KEYS)):
                problems.append(f"datasets.{name}.overrides.{case_id}.{old}: renamed to {RENAMED_CASE_KEYS[old]}")
    return problems


def _check_dataset(name: str, spec: dict, measured: dict) -> list[str]:
    """Checks the schema cannot express: the column (material, aspect_ratio and L_i, or a `measured`
    entry's), the material, range order, split fractions, overrides' case ids."""
    problems = []
    column = [key for key in COLUMN_KEYS if key in spec]
    if "measured" in spec:
        if column:
            problems.append(
                f"datasets.{name}: measured {spec['measured']!r} gives the column; leave out {column} (they are its)"
            )
        if spec["measured"] not in measured:
            problems.append(
                f"datasets.{name}.measured: {spec['measured']!r} is not an entry of `measured` "
                f"(entries: {sorted(measured)})"
            )
    elif len(column) < len(COLUMN_KEYS):
        missing = [key for key in COLUMN_KEYS if key not in spec]
        problems.append(f"datasets.{name}: {missing} missing; give {list(COLUMN_KEYS)}, or `measured: <entry>`")
    if "material" in spec:
        try:
            get_material(spec["material"])
        except CaseError as exc:
            problems.append(f"datasets.{name}.{exc}")
    for key in VARIED:
        value = spec.get(key)
        if isinstance(value, dict) and "range" in value and value["range"][0] > value["range"][1]:
            problems.append(f"datasets.{name}.{key}.range: {value['range']} must be [min, max] with min <= max")
    total = sum(spec["splits"].values())
    if not math.isclose(total, 1.0, abs_tol=1e-9):
        problems.append(f"datasets.{name}.splits: fractions {spec['splits']} must sum to 1 (got {total:g})")
    needed = sum(1 for s in SPLITS if spec["splits"][s] > 0)
    if spec["n_cases"] < needed:
        problems.append(f"datasets.{name}.n_cases: {spec['n_cases']} cases cannot fill {needed} non-empty splits")
    for case_id in spec.get("overrides", {}):
        if int(case_id.split("_")[1]) >= spec["n_cases"]:
            problems.append(
                f"datasets.{name}.overrides.{case_id}: no such case; ids run "
                f"{case_id_of(0, spec['n_cases'])}..{case_id_of(spec['n_cases'] - 1, spec['n_cases'])}"
            )
    return problems
