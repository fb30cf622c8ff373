"""The case table: every DEM run the DAG makes, one row each, built in one place (`case_table`).

A row is a dem.grid case-table row (every CollapseCase field of the case, plus dataset, case_id and
split), keyed "<dataset>/<case_id>". Four kinds of run fill it, each under a dataset of its own:

  - the configured datasets (datasets.<name>, dem.grid.case_table): the GNS training data;
  - the DoE's design runs of each column of doe.measured (dataset "doe_<name>", case_id = run_id,
    split "doe"; doe.study.case_rows);
  - the scale ladder (dataset "scale_ladder", split "scale_ladder"; dem.scale_ladder.case_rows);
  - the GNS dataset of each column's calibrated model (dataset "calibrated_<name>", `model_rows`),
    and of each campaign's model (dataset "campaign_<name>", its cases cycling through the
    campaign's columns or the geometries calibration.campaign_geometry gives: `campaign_templates`).
    Its parameters are the model's, which the diagnosis chooses when its jobs run
    (calibrated_model's model.json), so the table the DAG is planned from holds what gives them
    then: the case id and split, "calibrated" (the column's name), the template row (the first case
    of the base GNS's dataset of the column: its geometry, grain scale and frames), gns_cases,
    design_seed and channel_width (pipeline.calibrated_gns.model_case).

The DEM stage's rules (workflow/rules/dem.smk) build every row; a calibrated model's deck reads
its model.json too.
"""

from __future__ import annotations

import math

from calibration.measured import load_column, read_measured
from dem import grid, scale_ladder
from doe.design import design_from_config
from doe.study import case_rows as doe_case_rows
from pipeline.calibrated_gns import case_splits, model_gns_columns
from pipeline.campaign_geometry import fixed_by_config, given_duration, given_geometries
from pipeline.config import campaign_gns_names, gns_datasets


def doe_dataset(name: str) -> str:
    """The case-table dataset of the DoE design runs of measured column `name`."""
    return f"doe_{name}"


def model_dataset(name: str) -> str:
    """The case-table dataset of the GNS dataset of measured column `name`'s calibrated model."""
    return f"calibrated_{name}"


def campaign_dataset(name: str) -> str:
    """The case-table dataset of the GNS dataset of campaign `name`'s model."""
    return f"campaign_{name}"


def model_rows(config: dict, name: str, templates: list[dict], dataset: str) -> list[dict]:
    """The rows of `dataset`, the GNS dataset of measured entry `name`'s calibrated model; templates:
    the case-table rows its cases take their column from, case k the (k mod len)-th (one column:
    the base GNS's dataset's first; a campaign: one per column, campaign_templates)."""
    section = config["calibration"]
    fixed = {
        "dataset": dataset,
        "calibrated": name,
        "gns_cases": section["gns_cases"],
        "design_seed": section["seed"],
        "channel_width": config["diagnosis"]["channel_width"],
    }
    rows = case_splits(section)
    return [dict(row, **fixed, template=templates[k % len(templates)]) for k, row in enumerate(rows)]


def campaign_templates(config: dict, table: dict[str, dict], name: str) -> list[dict]:
    """One template row per geometry of campaign `name`'s GNS dataset: the first case of the config's
    first GNS dataset (its frame interval in seconds, one GNS step, and its other settings) on the
    campaign's material at the diagnosis' size_scale (the campaign's calibration scale). The
    geometries are calibration.campaign_geometry's where given (pipeline.campaign_geometry), simulated
    for its duration; else the campaign's columns', each simulated at least to its last measured t/t*."""
    base = dataset_rows(table, gns_datasets(config)[0])[0]
    columns = list(read_measured(config["measured"][name]).values())
    material = columns[0].material_properties.to_config()
    given = given_geometries(config, name)
    if given is not None:
        duration = given_duration(config, name, base)
        geometries = [(a, L_i, duration) for a, L_i in given]
    else:
        least = float(base.get("duration_over_tstar", 0.0))
        geometries = [(c.aspect_ratio, c.L_i, max(least, math.ceil(2 * c.t_over_tstar[-1]) / 2)) for c in columns]
    return [
        dict(
            base,
            material=material,
            aspect_ratio=a,
            L_i=L_i,
            size_scale=config["diagnosis"]["size_scale"],
            duration_over_tstar=duration,
        )
        for a, L_i, duration in geometries
    ]


def case_table(config: dict, inverse_datasets: dict[str, str]) -> dict[str, dict]:
    """{"<dataset>/<case_id>": row} of every DEM run of the validated, cross-checked `config`
    (pipeline.config.validate_config, check_cross_keys; inverse_datasets: what the latter returns,
    {column: the dataset of its base GNS}): its datasets, then the DoE's runs, the scale ladder's
    and the calibrated models' GNS datasets. A bad dataset case raises ConfigError naming the
    dataset, the case and the field; a bad DoE or ladder run, CaseError naming the field."""
    table = grid.case_table(config)
    rows = []
    doe = config["doe"]
    if doe["measured"]:
        design = design_from_config(doe)
        fields = {"size_scale": doe["size_scale"], "duration_over_tstar": doe["duration_over_tstar"]}
        for name in doe["measured"]:
            rows += doe_case_rows(design, load_column(config["measured"][name]), doe_dataset(name), **fields)
    rows += scale_ladder.case_rows(config["scale_ladder"])
    for name in model_gns_columns(config):
        rows += model_rows(config, name, [dataset_rows(table, inverse_datasets[name])[0]], model_dataset(name))
    for name in campaign_gns_names(config):
        fixed = fixed_by_config(config, name)  # the model's config, where it alone makes the cases
        campaign_rows = model_rows(config, name, campaign_templates(config, table, name), campaign_dataset(name))
        rows += [dict(row, model_by_config=fixed) for row in campaign_rows] if fixed else campaign_rows
    for row in rows:
        key = f"{row['dataset']}/{row['case_id']}"
        if key in table:  # check_cross_keys keeps the derived datasets' names free
            raise ValueError(f"case table: {key} twice")
        table[key] = row
    return table


def dataset_rows(table: dict[str, dict], dataset: str) -> list[dict]:
    """The rows of one dataset of the case table, in the table's (case_id) order."""
    return [row for row in table.values() if row["dataset"] == dataset]
