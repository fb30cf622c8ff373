"""Config validation, in one place: the schema check (pipeline/config_schema.py) and the checks across keys.

`validate_config` reads the numbers, booleans and nulls Snakemake's --config leaves as strings in
nested sections, checks a config against workflow/schemas/config.schema.yaml, adds the checks the
schema cannot express (range order, split fractions, overrides' case ids, each gns.per_dataset
entry as the gns section it makes, the runout method) and fills the defaults. `check_cross_keys`
then checks the keys that name another key's entries (a dataset, a `measured` entry, a GNS) against
the validated config and its case table (dem.grid.case_table), and applies the size guard
(dem.min_grains_across, dem.case.check_grains_across) to every DEM column the config builds.
workflow/rules/common.smk runs both once, so a bad config fails before any job runs; every problem
is a ConfigError naming the key.
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Iterable

from calibration.geometry import InverseDesignError, check_geometry_of_dataset, nearest_dataset
from calibration.measured import (
    MeasuredDataError,
    MeasuredDataWarning,
    check_one_material,
    first_lines,
    load_column,
    read_measured,
)
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import MechanismError, candidate_mechanisms, check_plausible_range, get_mechanisms
from calibration.model import Model
from calibration.residuals import MIN_RUNOUT_POINTS, MIN_SPARE_VALUES
from dem.case import (
    CaseError,
    CollapseCase,
    Material,
    check_grains_across,
    get_material,
    grains_across,
)
from dem.engines import ENGINES, EngineError, get_engine
from dem.grid import ConfigError, sample_dataset
from dem.scale_ladder import DATASET as LADDER_DATASET
from pipeline.campaign_geometry import check_campaign_geometry
from pipeline.config_schema import validate_config

__all__ = [
    "ConfigError",
    "validate_config",
    "derive_columns",
    "check_cross_keys",
    "check_datasets",
    "check_gns",
    "check_doe",
    "check_inverse",
    "check_diagnosis",
    "check_scale_ladder",
    "check_campaigns",
    "campaign_names",
    "campaign_gns_names",
    "gns_datasets",
    "inverse_datasets",
]


# --- what the measured columns need -----------------------------------------------------------------


def derive_columns(config: dict, added: Iterable[str] = ()) -> dict:
    """The validated `config` with what its measured columns need filled in (a new dict; deterministic).

    - A dataset with `measured: <entry>` gets that column's material, aspect_ratio and L_i (a
      material of the CSV's own as its {name, diameter, density, solid_fraction}).
    - `added`: the `measured` entries given on the command line (Snakemake's --config); one that no
      route names (doe.measured, inverse.measured) joins inverse.measured, so it is calibrated through
      a GNS like the config's own columns (diagnosis and calibrated model: every entry anyway).
    - An inverse.measured column without inverse.dataset that no GNS dataset holds (none of its
      material, or its geometry outside every one's: calibration.gns_objective) gets one: dataset
      `inverse_<name>`, the settings of the dataset whose GNS calibrates the config's other columns
      (else the first GNS dataset; its gns.per_dataset too) on the column's material, a and L_i, at
      that dataset's size_scale or the largest the size guard (dem.min_grains_across) lets the column
      take, its frames as many per t*, simulated at least to the last measured t/t*.
    Every material name means one material in every dataset and CSV. Raises ConfigError naming the
    key and, for a CSV, the file and line.
    """
    config = copy.deepcopy(config)
    campaigns = campaign_names(config)
    columns = {name: _measured_column(config, name) for name in config["measured"] if name not in campaigns}
    for dataset, spec in config["datasets"].items():
        if "measured" in spec:
            if spec["measured"] in campaigns:
                raise ConfigError(
                    _one_column_only(config, spec["measured"], f"datasets.{dataset}.measured", "a dataset")
                )
            column = columns[spec["measured"]]
            material = column.material_properties.to_config()
            spec.update(material=material, aspect_ratio=column.aspect_ratio, L_i=column.L_i)
    campaign_columns = {
        f"{name}/{column.name}": column for name in campaigns for column in _measured_columns(config, name).values()
    }
    _check_materials(config, {**columns, **campaign_columns})
    routed = set(config["doe"]["measured"]) | set(config["inverse"]["measured"])
    config["inverse"]["measured"] += [name for name in sorted(set(added)) if name in columns and name not in routed]
    for name in config["inverse"]["measured"]:
        if name in columns and not config["inverse"]["dataset"].get(name):
            _dataset_of_column(config, name, columns)
    return config


def campaign_names(config: dict) -> list[str]:
    """The `measured` entries that hold a campaign (several columns of one material), in name order;
    ConfigError naming the file, line and CSV column where an entry's columns are of several
    materials."""
    names = []
    for name in sorted(config["measured"]):
        if len(_measured_columns(config, name)) > 1:
            try:
                check_one_material(config["measured"][name])
            except MeasuredDataError as exc:
                raise ConfigError(f"config key measured.{name}: {exc}") from exc
            names.append(name)
    return names


def check_campaigns(config: dict, cases: dict[str, dict]) -> None:
    """calibration.campaign_geometry (pipeline.campaign_geometry.check_campaign_geometry): each entry
    names a campaign whose columns lie on the geometries given; cases: the case table."""
    campaigns = campaign_names(config)
    with_gns = campaign_gns_names(config)
    base = gns_datasets(config)[0] if with_gns else None
    base_row = next((row for row in cases.values() if row["dataset"] == base), None)
    columns = {name: _measured_columns(config, name) for name in campaigns}
    check_campaign_geometry(config, campaigns, columns, base_row)


def campaign_gns_names(config: dict) -> list[str]:
    """The campaigns whose model gets a GNS route (a dataset over the campaign's columns, a GNS, a
    search on it): with the calibrated stage and calibration.gns on and a GNS dataset in the config
    whose frame interval and settings the campaign's dataset takes (pipeline.cases.campaign_templates)."""
    section = config["calibration"]
    if not (section["enabled"] and section["gns"] and gns_datasets(config)):
        return []
    return campaign_names(config)


def _one_column_only(config: dict, name: str, key: str, what: str) -> str:
    """The message for `key` naming campaign entry `name` where `what` takes one column."""
    columns = list(_measured_columns(config, name))
    return (
        f"config key {key}: {name!r} ({config['measured'][name]}) is a campaign of columns {columns}; {what} "
        "takes one column: give it an entry of one column (the campaign stage calibrates the campaign as a "
        "whole, results/campaign/<name>)"
    )


def _measured_column(config: dict, name: str) -> MeasuredColumn:
    """The one column of `measured` entry `name` (its DoE, inverse design and datasets use one column)."""
    columns = _measured_columns(config, name)
    if len(columns) != 1:
        raise ConfigError(
            f"config key measured.{name}: {config['measured'][name]}: holds columns {list(columns)}; "
            "give a file of one column"
        )
    return next(iter(columns.values()))


def _check_materials(config: dict, columns: dict[str, MeasuredColumn]) -> None:
    """One material per name across the datasets and the measured CSVs."""
    seen: dict[str, tuple[Material, str]] = {}
    sources = [(get_material(spec["material"]), f"datasets.{n}.material") for n, spec in config["datasets"].items()]
    sources += [(c.material_properties, f"measured.{n} ({c.source})") for n, c in columns.items()]
    if config["scale_ladder"]["size_scales"]:
        sources.append((get_material(config["scale_ladder"]["material"]), "scale_ladder.material"))
    for material, where in sources:
        first = seen.setdefault(material.name, (material, where))
        if first[0] != material:
            raise ConfigError(
                f"config key {where}: material {material.name!r} is {material}, but {first[1]} gives {first[0]}; "
                "one name, one material"
            )


def _dataset_of_column(config: dict, name: str, columns: dict[str, MeasuredColumn]) -> None:
    """inverse.dataset[name]: the GNS dataset that holds the column, else a new one (derive_columns)."""
    with_gns, column = gns_datasets(config), columns[name]
    rows = [row for dataset in with_gns for row in sample_dataset(dataset, config["datasets"][dataset])]

    def holding(other: str) -> str | None:  # the GNS dataset that holds measured column `other`
        if config["inverse"]["dataset"].get(other):
            return config["inverse"]["dataset"][other]
        try:
            dataset = nearest_dataset(columns[other], rows, with_gns)
            check_geometry_of_dataset(columns[other], rows, dataset)
            return dataset
        except InverseDesignError:
            return None

    if holding(name):
        return  # inverse_datasets resolves it, as for any column
    others = [holding(n) for n in config["inverse"]["measured"] if n != name and n in columns]
    template = next((d for d in others if d), with_gns[0] if with_gns else None)
    dataset = f"inverse_{name}"
    if template is None or dataset in config["datasets"]:
        why = f"dataset {dataset!r} is taken" if template else "the config has no GNS dataset whose settings to copy"
        raise ConfigError(
            f"config key inverse.measured: {name!r} ({column.source}) has no GNS dataset of its material and geometry, "
            f"and {why}: add a dataset with `measured: {name}`"
        )
    spec = {k: copy.deepcopy(v) for k, v in config["datasets"][template].items() if k not in ("overrides", "measured")}
    material = column.material_properties
    largest = math.floor(column.L_i / (config["dem"]["min_grains_across"] * material.diameter) * 100) / 100
    heights = [float(row["aspect_ratio"]) * float(row["L_i"]) for row in rows if row["dataset"] == template]
    interval = spec["output_interval"] * math.sqrt(column.H_i / (sum(heights) / len(heights)))  # frames per t*
    last = max([float(column.t_over_tstar[-1])] + ([column.profile_time] if column.profile_x is not None else []))
    spec.update(
        measured=name,
        material=material.to_config(),
        aspect_ratio=column.aspect_ratio,
        L_i=column.L_i,
        size_scale=min(spec.get("size_scale", 1.0), max(largest, 1.0)),
        output_interval=float(f"{interval:.3g}"),
    )
    if last > spec.get("duration_over_tstar", CollapseCase.duration_over_tstar):
        spec["duration_over_tstar"] = math.ceil(last * 2) / 2
    config["datasets"][dataset] = spec
    if "datasets" in config["gns"]:
        config["gns"]["datasets"] = [*config["gns"]["datasets"], dataset]
    if template in config["gns"].get("per_dataset", {}):
        config["gns"]["per_dataset"][dataset] = copy.deepcopy(config["gns"]["per_dataset"][template])
    config["inverse"]["dataset"][name] = dataset


# --- keys that name another key's entries ------------------------------------------------------
def check_cross_keys(config: dict, cases: dict[str, dict]) -> dict[str, str]:
    """Every check across keys of the validated `config`, in stage order (datasets, GNS, DoE,
    inverse design, diagnosis, calibrated model, campaigns, scale ladder).

    cases: the case table of `config` ({"<dataset>/<case_id>": row}, dem.grid.case_table). Returns
    what the inverse-design checks resolve on the way, {inverse.measured name: the dataset whose
    GNS calibrates it} (inverse_datasets). Raises ConfigError naming the key.
    """
    check_datasets(config, cases)
    check_gns(config)
    check_doe(config)
    resolved = check_inverse(config, cases)
    check_diagnosis(config)
    check_calibration(config, resolved)
    check_campaigns(config, cases)
    check_scale_ladder(config)
    return resolved


# The size guard (dem.min_grains_across): one check, dem.case.check_grains_across, for every DEM
# column the config builds: the datasets' cases (GNS data), the DoE's runs, the diagnosis' runs.
def _guard(L_i: float, material: str | dict, size_scale: float, config: dict, where: str) -> None:
    try:
        check_grains_across(L_i, material, size_scale, config["dem"]["min_grains_across"], where)
    except CaseError as exc:
        raise ConfigError(f"config key {exc}") from exc


def _measured_columns(config: dict, name: str) -> dict[str, MeasuredColumn]:
    """The columns of `measured` entry `name` (the reader's warnings are left to the stage that uses them)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MeasuredDataWarning)
            return read_measured(config["measured"][name])
    except MeasuredDataError as exc:
        raise ConfigError(f"config key measured.{name}: {exc}") from exc


def check_datasets(config: dict, cases: dict[str, dict]) -> None:
    """The size guard on every case of every dataset (the case table `cases`): names the dataset,
    the case with the fewest grains across and every case under dem.min_grains_across."""
    for name in sorted(config["datasets"]):
        under = []
        for row in (row for row in cases.values() if row["dataset"] == name):
            try:
                _guard(row["L_i"], row["material"], row.get("size_scale", 1.0), config, name)
            except ConfigError:
                under.append(row)
        if under:
            worst = min(under, key=lambda row: grains_across(row["L_i"], row["material"], row.get("size_scale", 1.0)))
            ids = sorted(row["case_id"] for row in under)
            more = f" (cases under the minimum: {', '.join(ids)})" if len(ids) > 1 else ""
            where = f"datasets.{name}, case {worst['case_id']}{more}"
            _guard(worst["L_i"], worst["material"], worst.get("size_scale", 1.0), config, where)


def gns_datasets(config: dict) -> list[str]:
    """The datasets a GNS is trained on: gns.datasets, by default every dataset."""
    return config["gns"].get("datasets", sorted(config["datasets"]))


def gns_dataset_settings(config: dict, dataset: str) -> dict:
    """The training settings of one dataset's GNS (gns.train.TrainSettings' keys): the gns section
    without the stage's own keys (datasets, threads, per_dataset), gns.per_dataset[dataset] laid
    over it."""
    section = config["gns"]
    base = {k: v for k, v in section.items() if k not in ("datasets", "threads", "per_dataset")}
    return {**base, **section.get("per_dataset", {}).get(dataset, {})}


def check_gns(config: dict) -> None:
    """gns.datasets and gns.per_dataset name datasets."""
    datasets = sorted(config["datasets"])
    for key in ("datasets", "per_dataset"):
        for name in config["gns"].get(key, []):
            if name not in config["datasets"]:
                raise ConfigError(f"config key gns.{key}: {name!r} is not a dataset (datasets: {datasets})")


def check_doe(config: dict) -> None:
    """doe.measured names `measured` entries, no dataset takes the name of one's DoE runs, and each
    one's column passes the size guard (dem.min_grains_across) at doe.size_scale."""
    for name in config["doe"]["measured"]:
        if name not in config["measured"]:
            raise ConfigError(
                f"config key doe.measured: {name!r} is not an entry of `measured` "
                f"(entries: {sorted(config['measured'])})"
            )
        if f"doe_{name}" in config["datasets"]:
            raise ConfigError(f"config key datasets.doe_{name}: the name is taken by the DoE of measured {name!r}")
    campaigns = campaign_names(config)
    for name in config["doe"]["measured"]:  # the DoE runs on the file's one column (load_column, doe.smk)
        if name in campaigns:
            raise ConfigError(_one_column_only(config, name, "doe.measured", "the DoE of the paper's routes"))
        try:
            column = load_column(config["measured"][name])
        except MeasuredDataError as exc:
            raise ConfigError(f"config key doe.measured: {name!r}: {exc}") from exc
        size_scale = config["doe"]["size_scale"]
        _guard(column.L_i, column.material_properties, size_scale, config, f"doe.size_scale (measured {name!r})")


def check_inverse(config: dict, cases: dict[str, dict]) -> dict[str, str]:
    """inverse_datasets, then inverse.recovery_datasets name datasets with a GNS."""
    resolved = inverse_datasets(config, cases)
    with_gns = gns_datasets(config)
    for dataset in config["inverse"]["recovery_datasets"]:
        if dataset not in with_gns:
            raise ConfigError(
                f"config key inverse.recovery_datasets: {dataset!r} has no GNS (gns datasets: {with_gns})"
            )
    return resolved


def check_diagnosis(config: dict) -> None:
    """When diagnosis.enabled: every `measured` entry holds the points the diagnosis needs
    (_check_diagnosable) and every column of it passes the size guard (dem.min_grains_across) at
    diagnosis.size_scale (the diagnosis runs each column, read_measured)."""
    section = config["diagnosis"]
    if not section["enabled"]:
        return
    mechanisms = get_mechanisms(section["candidates"], section["channel_width"])
    largest = max(model.n_parameters for model in [Model()] + [Model(m) for m in mechanisms])
    for name in sorted(config["measured"]):
        columns = list(_measured_columns(config, name).values())
        _check_diagnosable(name, columns, largest)
        lines = first_lines(config["measured"][name])
        for column in columns:
            where = (
                f"diagnosis.size_scale (measured {name!r}: {column.source}, line {lines[column.name]}, column 'L_i' "
                f"of measured column {column.name!r})"
            )
            _guard(column.L_i, column.material_properties, section["size_scale"], config, where)


def _check_diagnosable(name: str, columns: list[MeasuredColumn], largest: int) -> None:
    """The counts calibration.residuals.check_data asks of the columns of `measured` entry `name`, one
    file: MIN_RUNOUT_POINTS runout points per column, and MIN_SPARE_VALUES measured values (runout
    and profile points) beyond the `largest` number of parameters of a diagnosis model."""
    for column in columns:
        if len(column.t_over_tstar) < MIN_RUNOUT_POINTS:
            raise ConfigError(
                f"config key measured.{name}: {column.source}: column {column.name!r} has {len(column.t_over_tstar)} "
                f"runout point(s); the diagnosis (diagnosis.enabled) needs at least {MIN_RUNOUT_POINTS} per column "
                "(a curve, not a point): add runout rows, or set diagnosis.enabled: false"
            )
    values = sum(len(c.t_over_tstar) + (0 if c.profile_x is None else len(c.profile_x)) for c in columns)
    if values < largest + MIN_SPARE_VALUES:
        raise ConfigError(
            f"config key measured.{name}: {columns[0].source}: {values} measured value(s) (runout and profile "
            f"points); the diagnosis compares models of up to {largest} parameters (diagnosis.candidates) and needs "
            f"at least {largest + MIN_SPARE_VALUES} (parameters + {MIN_SPARE_VALUES}): add runout rows, or set "
            "diagnosis.enabled: false"
        )


def check_scale_ladder(config: dict) -> None:
    """The scale ladder's runs (dataset scale_ladder of the case table) take a name no dataset has,
    and its column passes the size guard (dem.min_grains_across) at its coarsest size_scale."""
    section = config["scale_ladder"]
    if not section["size_scales"]:
        return
    if LADDER_DATASET in config["datasets"]:
        raise ConfigError(f"config key datasets.{LADDER_DATASET}: the name is taken by the runs of scale_ladder")
    coarsest = max(section["size_scales"])
    _guard(section["L_i"], section["material"], coarsest, config, f"scale_ladder.size_scales ({coarsest:g})")


def check_calibration(config: dict, inverse_datasets: dict[str, str] | None = None) -> None:
    """calibration.model auto needs the diagnosis; a mechanism the chosen dem.engine cannot run (for
    auto: any diagnosis candidate) is refused before any job runs; so is a Bayesian optimisation
    budget below its initial design, and a warm-started model GNS of another width than the base's
    (the base GNS of each column: inverse_datasets, {measured name: dataset}, as check_inverse
    resolves them, with its gns.per_dataset; None: the gns section's width)."""
    section = config["calibration"]
    if not section["enabled"] or not config["measured"]:
        return
    for name in config["measured"]:
        if f"campaign_{name}" in config.get("datasets", {}):
            raise ConfigError(
                f"config key datasets.campaign_{name}: the name is taken by the GNS dataset of measured {name!r}"
            )
        if f"calibrated_{name}" in config.get("datasets", {}):
            raise ConfigError(
                f"config key datasets.calibrated_{name}: the name is taken by the GNS dataset of the calibrated "
                f"model of measured {name!r}"
            )
    if section["gns_optimiser"] == "bayesopt" and section["gns_budget"] < section["gns_n_initial"]:
        raise ConfigError(
            f"config key calibration.gns_budget: {section['gns_budget']} GNS points cannot hold the "
            f"{section['gns_n_initial']} of the initial design (calibration.gns_n_initial)"
        )
    width, gns = section["gns_latent_size"], config["gns"]
    if section["gns_warm_start"] and section.get("gns_shared"):
        raise ConfigError(
            "config key calibration.gns_shared: one GNS for both models replaces the base model's GNS, but "
            "calibration.gns_warm_start starts the model's GNS from it; turn one of them off"
        )
    warm_started = (inverse_datasets or {None: None}).values() if section["gns_warm_start"] and width else ()
    for dataset in warm_started:
        base_width = gns.get("per_dataset", {}).get(dataset, {}).get("latent_size", gns.get("latent_size"))
        if width != base_width:
            base = f"the base GNS of {dataset}" if dataset else "the base GNS"
            raise ConfigError(
                f"config key calibration.gns_latent_size: {width}, but calibration.gns_warm_start starts the model's "
                f"GNS from {base}, {base_width} wide (gns.latent_size or its gns.per_dataset); set it to null or "
                f"{base_width}, or train from scratch"
            )
    if section["gns_warm_start"] and section["gns_learning_rate_decay_steps"] is not None:
        raise ConfigError(
            "config key calibration.gns_learning_rate_decay_steps: sets the schedule of a model GNS trained from "
            "scratch, but calibration.gns_warm_start fine-tunes the base GNS on its own schedule; set it to null"
        )
    check_target_scale(config)
    check_plausible_ranges(config)
    model = section["model"]
    if model == "auto" and not config["diagnosis"]["enabled"]:
        raise ConfigError(
            "config key calibration.model: auto takes the diagnosis' answer, but diagnosis.enabled is false; "
            "name the model (base or a mechanism) or enable the diagnosis"
        )
    pairs = section.get("contender_pairs", "auto") if model == "auto" and section.get("scaling_check", True) else []
    for k, pair in enumerate([] if pairs == "auto" else pairs):
        if pair[0] == pair[1]:
            raise ConfigError(f"config key calibration.contender_pairs[{k}]: {pair} pairs {pair[0]} with itself")
    if model == "auto":
        names = list(config["diagnosis"]["candidates"] or candidate_mechanisms())
        names += [m for pair in ([] if pairs == "auto" else pairs) for m in pair if m not in names]
    else:
        names = [] if model == "base" else model.split("+")
        if len(set(names)) < len(names):
            raise ConfigError(f"config key calibration.model: {model} pairs {names[0]} with itself")
    name = config["dem"]["engine"]
    try:  # auto: the engine it picks on this machine; a named one need not be installed to be judged
        engine = get_engine(name, config["dem"]) if name == "auto" else ENGINES[name]
    except EngineError as exc:
        raise ConfigError(f"config key dem.engine: {exc}") from exc
    fields = {m.name: m.engine_field for m in get_mechanisms(names, config["diagnosis"]["channel_width"])}
    missing = [name for name, field in fields.items() if field not in engine.mechanisms]
    if missing:
        given_pairs = model == "auto" and pairs != "auto" and len(pairs) > 0
        what = "the model" if model != "auto" else f"the diagnosis candidates{' and contender pairs' * given_pairs}"
        raise ConfigError(
            f"config key calibration.model: {model} calibrates {what} {missing}, which dem.engine {engine.name} "
            f"cannot run (it runs {list(engine.mechanisms) or 'none of the candidate mechanisms'}); use the "
            "builtin engine, or name a model it can run (with auto: narrow diagnosis.candidates)"
        )


def check_target_scale(config: dict) -> None:
    """calibration.target_size_scale is not coarser than the calibration's (diagnosis.size_scale),
    finer_size_scale is finer than the target's (held out), and every measured column passes the
    size guard (dem.min_grains_across) at both."""
    section, coarse = config["calibration"], config["diagnosis"]["size_scale"]
    target, finer = section.get("target_size_scale"), section.get("finer_size_scale")
    if target is not None and target > coarse:
        raise ConfigError(
            f"config key calibration.target_size_scale: {target:g} is coarser than the calibration's size_scale "
            f"{coarse:g} (diagnosis.size_scale); the answer is carried to finer grains, not coarser"
        )
    reference = target if target is not None else coarse
    if finer is not None and finer >= reference:
        what = "the target's (calibration.target_size_scale)" if target is not None else "the calibration's"
        raise ConfigError(
            f"config key calibration.finer_size_scale: {finer:g} is not finer than {what} {reference:g}; the "
            "transfer is checked on finer grains than the answer was carried to"
        )
    campaigns = campaign_names(config)  # a campaign is calibrated at the diagnosis' scale alone
    for key, size_scale in (("target_size_scale", target), ("finer_size_scale", finer)):
        for name in sorted(set(config["measured"]) - set(campaigns)) if size_scale is not None else ():
            for column in _measured_columns(config, name).values():
                where = f"calibration.{key} (measured {name!r}, column {column.name!r})"
                _guard(column.L_i, column.material_properties, size_scale, config, where)


def check_plausible_ranges(config: dict) -> None:
    """Every range of calibration.plausible_ranges names a known mechanism and meets its bounds."""
    known = candidate_mechanisms(config["diagnosis"]["channel_width"])
    for material, stated in config["calibration"].get("plausible_ranges", {}).items():
        for name, entry in stated.items():
            key = f"calibration.plausible_ranges.{material}.{name}"
            if name not in known:
                raise ConfigError(f"config key {key}: {name!r} is not a candidate mechanism (known: {list(known)})")
            try:
                check_plausible_range(known[name], *map(float, entry["range"]))
            except MechanismError as exc:
                raise ConfigError(f"config key {key}: {exc}") from exc


def inverse_datasets(config: dict, cases: dict[str, dict]) -> dict[str, str]:
    """{inverse.measured name: the dataset whose GNS calibrates it}, checked.

    The dataset is inverse.dataset[name], by default the GNS dataset of the column's material with
    the nearest training column. Each name must be a `measured` entry, its dataset must have a GNS,
    and the column must lie in the geometry that GNS is trained on (a GeometryWarning when it is
    far from every training column). Reads each named measured CSV (paths relative to the cwd).
    """
    inverse, with_gns, rows = config["inverse"], gns_datasets(config), list(cases.values())
    campaigns = campaign_names(config)
    resolved = {}
    for name in inverse["measured"]:
        if name not in config["measured"]:
            raise ConfigError(
                f"config key inverse.measured: {name!r} is not an entry of `measured` "
                f"(entries: {sorted(config['measured'])})"
            )
        if name in campaigns:
            raise ConfigError(_one_column_only(config, name, "inverse.measured", "the GNS inverse design of the paper"))
        column = load_column(config["measured"][name])
        dataset = inverse["dataset"].get(name)
        if not dataset:
            try:
                dataset = nearest_dataset(column, rows, with_gns)
            except InverseDesignError as exc:
                raise ConfigError(
                    f"config key inverse.measured: {name!r} has no GNS dataset to calibrate it: {exc}"
                ) from exc
        if dataset not in with_gns:
            raise ConfigError(f"config key inverse.dataset.{name}: {dataset!r} has no GNS (gns datasets: {with_gns})")
        try:
            check_geometry_of_dataset(column, rows, dataset)
        except InverseDesignError as exc:
            raise ConfigError(
                f"config key inverse.measured: {name!r} cannot be calibrated with the GNS of dataset {dataset!r}: {exc}"
            ) from exc
        for key in ("friction", "restitution"):  # the GNS knows the range its dataset's cases span
            bounds = inverse.get(key)
            values = [float(row[key]) for row in rows if row["dataset"] == dataset]
            if bounds is not None and (bounds[0] < min(values) - 1e-9 or bounds[1] > max(values) + 1e-9):
                raise ConfigError(
                    f"config key inverse.{key}: bounds [{bounds[0]:g}, {bounds[1]:g}] leave the range the GNS of "
                    f"dataset {dataset!r} is trained on, [{min(values):.4g}, {max(values):.4g}] (its cases' {key}): "
                    "the GNS would extrapolate; narrow the bounds or widen the dataset's range"
                )
        resolved[name] = dataset
    return resolved
