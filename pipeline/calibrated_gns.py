"""The GNS route of the calibrated model (workflow/rules/calibrated.smk): a GNS dataset of the
measured column that varies every parameter of the model the DAG chose (model.json), the GNS
trained on it (rule gns_train: from scratch, or warm-started from the base model's GNS of the
column with calibration.gns_warm_start), and the
inverse design over all of the model's parameters with its Laplace posterior.

  - `model_case` (rule dem_deck, through pipeline.dem.write_deck): one case of the dataset, the
    DEM stage's rules run it; its trajectory records every parameter of the model (a mechanism's
    as its own attribute, e.g. bond_number);
  - `model_parameter_names` (rule dataset, through pipeline.dataset.build): the GNS's inputs;
  - the inverse design (rule calibrated_inverse): pipeline/calibrated_inverse.py, apart so that the
    DEM jobs here load no torch.

The methods are calibration/calibrated.py's (the design).
"""

from __future__ import annotations

import logging

from calibration.calibrated import model_dataset_cases, read_model
from calibration.model import Model, model_named
from dem.atomic import StrPath
from dem.case import CollapseCase
from dem.grid import assign_splits, case_from_row, case_id_of

log = logging.getLogger(__name__)


def model_gns_settings(
    base: dict,
    steps: int,
    init_from: str | None = None,
    learning_rate: float | None = None,
    latent_size: int | None = None,
    decay_steps: int | None = None,
) -> dict:
    """The `gns` settings of a calibrated model's GNS: those of the base GNS of the column (`base`,
    the config's gns section for that dataset) for `steps` steps.

    From scratch by default: the base's learning rate, falling tenfold over `decay_steps` (None: over
    the `steps`, as the 12000-step run that learnt the Bond number, docs/experiments/gns-route.md; the schedule does
    not depend on `steps`, so a shorter run repeats the first steps of a longer one bit for bit). With
    `init_from`, a warm start from the weights there at `learning_rate`, the base's schedule
    compressed in proportion (a fine-tuning: a start at the base's 1e-3 undid it, the validation
    runout MSE 2.7 -> 0.40 in 6000 steps against 0.39 after 1000 at 3e-4). A warm start costs a
    quarter of the steps but does not learn what cohesion does (the Bond number's slope of L* stayed
    flat however it was fine-tuned), so the DAG trains from scratch. latent_size: the width from
    scratch (None: the base's); a warm start keeps the base's (pipeline.config refuses another)."""
    from gns.settings import TrainSettings

    if init_from is None:
        width = {} if latent_size is None else {"latent_size": latent_size}
        return {**base, **width, "steps": steps, "learning_rate_decay_steps": decay_steps or steps}
    filled = TrainSettings.from_config(base)
    decay = max(1, round(filled.learning_rate_decay_steps * steps / filled.steps))
    return {
        **base,
        "steps": steps,
        "learning_rate_decay_steps": decay,
        "learning_rate": learning_rate or filled.learning_rate,
        "init_from": str(init_from),
    }


def model_gns_columns(config: dict) -> list[str]:
    """The measured columns whose calibrated model gets a GNS route of its own (a dataset, a GNS,
    an inverse design): with the calibrated stage and calibration.gns on and a model other than
    the base one, each column the base GNS calibrates (inverse.measured), in name order."""
    section = config["calibration"]
    if not (section["enabled"] and section["gns"]) or section["model"] == "base":
        return []
    return [name for name in sorted(config["measured"]) if name in config["inverse"]["measured"]]


def case_splits(section: dict) -> list[dict]:
    """[{case_id, split}] of a calibrated model's GNS dataset (section: the config's `calibration`):
    known before the model is, so the DAG's shape does not wait for the diagnosis."""
    n_cases = section["gns_cases"]
    return [
        {"case_id": case_id_of(k, n_cases), "split": split}
        for k, split in enumerate(assign_splits(n_cases, section["gns_splits"]))
    ]


def start_packing_cases(section: dict) -> list[str]:
    """Case ids of the model's GNS dataset whose first frames start the inverse design's rollouts
    besides the start run (section: the config's `calibration`): start_packings - 1 training cases,
    spread over the case order (the mechanism's parameter), known at parse time."""
    train = [row["case_id"] for row in case_splits(section) if row["split"] == "train"]
    wanted = section["start_packings"] - 1
    if wanted > len(train):
        raise ValueError(
            f"calibration.start_packings: {section['start_packings']} needs {wanted} training cases besides the "
            f"start run; the model's dataset has {len(train)} (calibration.gns_cases, gns_splits)"
        )
    if wanted <= 0:
        return []
    return [train[round(k * (len(train) - 1) / max(wanted - 1, 1))] for k in range(wanted)]


def model_case(model_json: StrPath | None, row: dict) -> tuple[CollapseCase, dict[str, float]]:
    """The case of one case-table row of a calibrated model's GNS dataset (pipeline.cases.model_rows:
    its template row, gns_cases, design_seed and channel_width) under the model of model_json (or of
    the row's model_by_config, pipeline.campaign_geometry.fixed_by_config), and the model's
    parameters there, {name: value} (the trajectory records them: the GNS's inputs)."""
    model = row_model(model_json, row)
    design = model_dataset_cases(model, case_from_row(row["template"]), row["gns_cases"], row["design_seed"])
    cases = {c.case_id: c for c in design}
    if row["case_id"] not in cases:
        raise KeyError(f"{model_json}: the {model.name} dataset has no case {row['case_id']} (it has {len(cases)})")
    case = cases[row["case_id"]]
    log.info("%s: %s", row["case_id"], case.parameters)
    return case.case, case.parameters


def row_model(model_json: StrPath | None, row: dict) -> Model:
    """The model of a row of a calibrated model's GNS dataset: that of its model_by_config record,
    else model_json's."""
    if row.get("model_by_config"):
        return config_model(row["model_by_config"])
    if model_json is None:
        raise ValueError(f"{row['dataset']}/{row['case_id']}: a calibrated model's case needs its model.json")
    return read_model(model_json, row["channel_width"])[0]


def config_model(record: dict) -> Model:
    """The model of a model_by_config record (pipeline.campaign_geometry.fixed_by_config): the model
    the config names, over its whole range."""
    return model_named(record["model"], record["channel_width"])


def model_parameter_names(model_json: StrPath) -> tuple[str, ...]:
    """The parameters of the model of model_json, in its order: those its GNS dataset varies (the
    channel width changes a mechanism's fields, not its name)."""
    model, why = read_model(model_json)
    log.info("the %s model (%s): parameters %s", model.name, why, list(model.parameter_names))
    return tuple(model.parameter_names)


def model_off_settings(model_json: StrPath) -> dict[str, float | str]:
    """{parameter: off setting} of each mechanism of the model of model_json (Mechanism.off_setting):
    what the base model's runs hold, for a GNS trained on both models' runs."""
    model, _ = read_model(model_json)
    return {m.parameter: m.off_setting() for m in model.mechanisms}
