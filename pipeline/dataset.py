"""The dataset stage (workflow/rules/dataset.smk): the trajectories of each named dataset ->
metadata JSON (splits, normalisation statistics; gns.dataset) -> summary figure + case table CSV
with each case's final L* (the report section, results/report/dataset.md: pipeline/dataset_section.py).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

from dem.atomic import StrPath
from dem.grid import write_case_table
from dem.runout import RunoutMethod
from gns.dataset import DEM_PARAMETERS, build_dataset, load_dataset_metadata, plot_dataset

log = logging.getLogger(__name__)
# where the DEM stage writes a case's trajectory; the same path as in dataset.smk
TRAJECTORY = "results/dem/{dataset}/trajectories/{case_id}.h5"


def build(
    splits: Mapping[str, Sequence[str]],
    out_path: StrPath,
    name: str,
    model_json: StrPath | None = None,
    model_by_config: Mapping | None = None,
    base_splits: Mapping[str, Sequence[str]] | None = None,
) -> dict:
    """Build dataset `name`'s metadata JSON at `out_path` (gns.dataset.build_dataset) from its
    trajectories, {"train"|"valid"|"test": [HDF5 paths]}. The DEM parameters the GNS takes: the
    paper's (mu, e), or for a calibrated model's GNS dataset every parameter of its model: that of
    model_json, or of its rows' model_by_config (a campaign's dataset that the config alone
    makes: pipeline.campaign_geometry.fixed_by_config). base_splits: the base model's runs of the
    same column (calibration.gns_shared), joined to each split with the model's mechanisms off
    (their off values recorded as parameter_off), so that one GNS serves both models. Returns the
    metadata dict."""
    off = None
    if model_json is None and not model_by_config:
        parameters = DEM_PARAMETERS
    else:  # imported here: the datasets of the paper's (mu, e) load no calibration code
        from pipeline.calibrated_gns import config_model, model_off_settings, model_parameter_names

        parameters = (
            config_model(model_by_config).parameter_names if model_json is None else model_parameter_names(model_json)
        )
        if base_splits and model_json is not None:
            off = model_off_settings(model_json)
    splits = {k: list(v) for k, v in splits.items()}
    if base_splits:
        if off is None:
            raise ValueError(f"dataset {name}: the base model's runs join only a calibrated model's dataset")
        splits = {k: splits.get(k, []) + list(base_splits.get(k, [])) for k in {*splits, *base_splits}}
        log.info("dataset %s: the base model's runs joined, its mechanisms off at %s", name, off)
    log.info("dataset %s: %s cases", name, {k: len(v) for k, v in splits.items()})
    metadata = build_dataset(splits, out_path, name, tuple(parameters), off)
    log.info(
        "dt_frame %.4g s, %d-%d grains, velocity std %s m/frame, acceleration std %s m/frame^2",
        metadata["dt_frame"],
        metadata["n_particles"]["min"],
        metadata["n_particles"]["max"],
        metadata["velocity_std"],
        metadata["acceleration_std"],
    )
    return metadata


def summarise(
    metadata_path: StrPath,
    figure_path: StrPath,
    cases_path: StrPath,
    rows: Sequence[Mapping],
    runout: RunoutMethod | dict | str,
) -> list[dict]:
    """One dataset's summary figure (cases by split, runout curves read by `runout`) at
    `figure_path` and its case table as CSV at `cases_path`: the case-table `rows` of the dataset
    with each case's final L* (column final_L_star, 4 decimals). Returns those rows."""
    metadata = load_dataset_metadata(metadata_path)
    final_runout = plot_dataset(metadata, figure_path, runout)
    rows = [dict(row) for row in rows]
    for row in rows:  # final L* beside the parameters
        path = TRAJECTORY.format(dataset=row["dataset"], case_id=row["case_id"])
        row["final_L_star"] = round(final_runout[path], 4)
    write_case_table(rows, cases_path)
    log.info(
        "summary of %s: %d cases, final L* %.3g-%.3g",
        metadata["name"],
        len(rows),
        min(final_runout.values()),
        max(final_runout.values()),
    )
    return rows
