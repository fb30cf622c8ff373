# Shared by every stage: the validated config, the case table, the sections and column lists the
# stages share, and the two lists each stage appends to. Logic lives in pipeline/config.py
# (validation) and pipeline/cases.py (the case table); this file only calls them.
import os
from pathlib import Path

import dem.grid
import dem.runout
import doe.design
import pipeline.calibrated_gns
import pipeline.cases
import pipeline.config
import pipeline.dem
from snakemake.io import get_flag_value, is_flagged
from snakemake.utils import min_version

min_version("9.0")

# Fails before any job runs, naming the key and what it allows; fills schema defaults.
config.update(pipeline.config.validate_config(config, Path(workflow.basedir, "workflow/schemas/config.schema.yaml")))
# What the measured columns need (README "Calibrate your own column"): a dataset's `measured:`
# column, and a GNS dataset for each column the inverse design calibrates and no dataset holds; a
# column given on the command line (--config measured=...) joins the GNS inverse design; one of a
# --configfile does not (Snakemake's overwrite_config holds both: config_settings.config is --config's).
config.update(pipeline.config.derive_columns(config, ((workflow.config_settings.config or {}).get("measured") or {})))

DATASETS = sorted(config["datasets"])
# Keys that name another key's entries (gns.datasets, doe.measured, inverse.*: a dataset, a
# `measured` entry, a GNS) and the size guard (dem.min_grains_across: every dataset case, DoE and
# diagnosis column) checked once, before any job runs. On the way it resolves the dataset
# whose GNS calibrates each inverse.measured column: {name: dataset} (inverse.smk).
INVERSE_DATASET = pipeline.config.check_cross_keys(config, dem.grid.case_table(config))
# The case table, built once (pipeline.cases.case_table): {"<dataset>/<case_id>": row} of every DEM
# run of the DAG: the datasets' cases, the DoE's design runs (dataset doe_<name>), the scale
# ladder's and the calibrated models' GNS datasets (calibrated_<name>: their parameters read from
# model.json when their decks are written). A row holds every CollapseCase field of the case plus
# dataset, case_id and split (a calibrated model's: what gives them). No later file adds to it.
CASES = pipeline.cases.case_table(config, INVERSE_DATASET)
# The sections and column lists of the stages, read here so that the helpers below read nothing a
# later rule file defines.
DOE = config["doe"]
DOE_NAMES = DOE["measured"]
DOE_DESIGN = doe.design.design_from_config(DOE)
DOE_RUNS = list(DOE_DESIGN["run_id"])
INVERSE = config["inverse"]
INVERSE_NAMES = INVERSE["measured"]
CALIBRATION = config["calibration"]
# auto chooses among the contenders by what they predict across aspect ratios (calibrated.smk)
SCALING_CHECK = CALIBRATION["model"] == "auto" and config["diagnosis"]["enabled"] and CALIBRATION["scaling_check"]
# A `measured` entry of several columns is a campaign, calibrated as one parameter set (campaign.smk);
# every other entry is one column, calibrated by calibrated.smk.
CAMPAIGN_NAMES = pipeline.config.campaign_names(config) if CALIBRATION["enabled"] else []
CALIBRATED_NAMES = sorted(set(config["measured"]) - set(CAMPAIGN_NAMES)) if CALIBRATION["enabled"] else []
# The campaigns whose model has a GNS route: a dataset campaign_<name> over their columns, whose
# frames and settings are those of the config's first GNS dataset (GNS_TEMPLATE_DATASET).
CAMPAIGN_GNS_NAMES = pipeline.config.campaign_gns_names(config)
GNS_TEMPLATE_DATASET = (pipeline.config.gns_datasets(config) or [None])[0]
CHANNEL_WIDTH = config["diagnosis"]["channel_width"]
# The columns whose calibrated model has a GNS route: its dataset calibrated_<name> (the case table).
MODEL_GNS_NAMES = pipeline.calibrated_gns.model_gns_columns(config)
# calibration.gns_shared: the columns whose model's GNS also runs the base model's route, {name: the
# base GNS dataset whose runs join the model's dataset, mechanism off}; and the base datasets whose
# own GNS that makes needless (every column their GNS calibrates is one of them): {dataset: [the
# model datasets whose GNS takes its place]} (gns.smk's GNS_DATASETS).
SHARED_GNS = {name: INVERSE_DATASET[name] for name in MODEL_GNS_NAMES} if CALIBRATION["gns_shared"] else {}
REPLACED_GNS = {
    base: [f"calibrated_{name}" for name in SHARED_GNS if SHARED_GNS[name] == base]
    for base in sorted(set(SHARED_GNS.values()))
    if all(name in SHARED_GNS for name, dataset in INVERSE_DATASET.items() if dataset == base)
}
# How every stage reads L* off a run (dem.runout.RunoutMethod), read once here and passed to every
# rule that scores a runout as a param, so changing it reruns exactly those rules. In the class's
# key order: Snakemake compares params as written, so keys reordered in a config would rerun them.
RUNOUT = dem.runout.RunoutMethod.from_config(config["runout"]).to_config()
# The engine of every DEM run outside the DEM stage's own rules (validations, Bayesian optimisation,
# recovery targets): the same engine and solver paths as the case table's runs.
DEM_ENGINE = {"engine": config["dem"]["engine"], "solvers": config["dem"]["solvers"]}

# Every stage appends the files `rule all` must build ...
FINAL_TARGETS = []
# ... and its report fragment: (title, "results/report/<stage>.md"), in report order.
REPORT_SECTIONS = []


wildcard_constraints:
    dataset=r"[A-Za-z0-9_\-]+",
    case_id=r"[A-Za-z0-9_\-]+",
    route=r"[a-z0-9\-]+",


# Conventions for every stage (pipeline/report.py and pipeline/benchmarks.py read them):
#   log:       results/logs/<stage>/<rule>[/<wildcards>].log
#   benchmark: results/benchmarks/<stage>/<rule>[/<wildcards>].tsv  -> the report's time table
#   report:    results/report/<stage>.md, links relative to that file; register it with
#              REPORT_SECTIONS.append(("Title", "results/report/<stage>.md"))
def case_row(wildcards):
    """The case-table row of a {dataset}/{case_id} job (used as params, so editing one case in the
    config reruns that case's jobs only)."""
    return CASES[f"{wildcards.dataset}/{wildcards.case_id}"]


def dataset_cases(dataset):
    """Rows of one dataset, in case_id order. A calibrated model's GNS dataset has case ids and
    splits only: its parameters come from its model.json."""
    return pipeline.cases.dataset_rows(CASES, dataset)


def model_column(dataset):
    """The measured column whose calibrated model's GNS dataset `dataset` is; None for any other."""
    rows = dataset_cases(dataset)
    return rows[0].get("calibrated") if rows else None


def model_json(dataset):
    """[the model.json whose model gives the cases of `dataset`]: a calibrated model's GNS dataset's
    (dem.smk, dataset.smk); [] for any other, and for a campaign's dataset that the config alone
    makes (its rows hold its model: pipeline.campaign_geometry.fixed_by_config)."""
    column = model_column(dataset)
    if not column or dataset_cases(dataset)[0].get("model_by_config"):
        return []
    return [f"results/calibrated/{column}/model.json"]


# Helpers of the stages, kept here so that no stage file mixes functions with rules (snakemake
# --lint). They read only the names above, so any stage may call them at parse time.


def dataset_trajectories(dataset):
    """{split: [trajectory paths]} of a dataset, from the case table (dataset.smk)."""
    splits = {"train": [], "valid": [], "test": []}
    for row in dataset_cases(dataset):
        splits[row["split"]].append(f"results/dem/{dataset}/trajectories/{row['case_id']}.h5")
    return splits


def shared_base_splits(dataset):
    """{split: [trajectory paths]} of the base model's runs that join `dataset`, the model's GNS
    dataset of a column of SHARED_GNS (dataset.smk); {} for any other dataset."""
    column = model_column(dataset)
    if column not in SHARED_GNS or dataset != f"calibrated_{column}":
        return {}
    return dataset_trajectories(SHARED_GNS[column])


def gns_dem_datasets(dataset):
    """The datasets whose DEM runs the GNS of `dataset` trains on: itself, and the base dataset its
    model's GNS shares (SHARED_GNS)."""
    column = model_column(dataset)
    if column in SHARED_GNS and dataset == f"calibrated_{column}":
        return [dataset, SHARED_GNS[column]]
    return [dataset]


def gns_settings(dataset):
    """Training settings of one dataset: the gns section with gns.per_dataset[dataset] laid over it
    (gns.smk); a calibrated model's GNS dataset takes the settings of the base GNS of its column
    for calibration.gns_steps, from scratch or warm-started from that GNS (gns_init)."""
    if model_column(dataset):
        name = model_column(dataset)
        # a campaign has no base GNS: its dataset's settings are those of the config's first GNS
        # dataset (pipeline.cases.campaign_templates), its GNS trained from scratch
        template = INVERSE_DATASET.get(name, GNS_TEMPLATE_DATASET)
        base = gns_settings(template)
        init = gns_init(dataset)
        return pipeline.calibrated_gns.model_gns_settings(
            base,
            CALIBRATION["gns_steps"],
            init[0] if init else None,
            CALIBRATION["gns_learning_rate"],
            CALIBRATION["gns_latent_size"],
            CALIBRATION["gns_learning_rate_decay_steps"],
        )
    return pipeline.config.gns_dataset_settings(config, dataset)


def gns_init(dataset):
    """[the GNS a dataset's training starts from]: the base GNS of the column of a calibrated
    model's GNS dataset with calibration.gns_warm_start; [] otherwise: from scratch (gns.smk)."""
    if not model_column(dataset) or not CALIBRATION["gns_warm_start"] or model_column(dataset) not in INVERSE_DATASET:
        return []
    return [inverse_gns(model_column(dataset), "model")]


# The routes of a campaign (campaign.smk).
CAMPAIGN_ROUTES = ["doe", "bayesopt", "gns"]


def campaign_routes(name):
    """The routes of campaign `name`: the DoE and the BO on DEM, and the GNS where its model has one."""
    return [r for r in CAMPAIGN_ROUTES if r != "gns" or name in CAMPAIGN_GNS_NAMES]


def campaign_gns_inputs(wildcards):
    """The GNS route's inputs: the GNS of the campaign's dataset, its metadata and the dataset's DEM
    runs (their first frames start the rollouts of each column); none for the other routes."""
    if wildcards.route != "gns":
        return {}
    dataset = f"campaign_{wildcards.name}"
    return {
        "gns": f"results/gns/{dataset}/train/model_best.pt",
        "metadata": f"results/datasets/{dataset}/metadata.json",
        "dataset": [p for paths in dataset_trajectories(dataset).values() for p in paths],
    }


def dem_resources(wildcards, stage, threads, attempt):
    """runtime (min) and mem_mb of a DEM job from its case-table row (pipeline.dem.job_resources)."""
    return pipeline.dem.job_resources(case_row(wildcards), stage, threads, attempt)


def critical_priority(dataset):
    """Scheduling priority of a dataset's jobs. The DAG's longest paths run through the GNS of an
    inverse-design column and the calibrated model's GNS (DEM runs -> diagnosis -> the model's DEM
    runs -> its GNS -> inverse design -> validation): first in the queue, so that the many shorter
    jobs fill the other core around them (dem.smk, dataset.smk, gns.smk). The base dataset of a
    column whose model has a GNS starts that GNS's inverse design (inverse_start), and where one GNS
    runs both models (SHARED_GNS) the DoE's runs feed its base inverse design (inverse.smk): they
    hold the model chain's priority too; the other base and DoE datasets, the answer's."""
    feeds_chain = {INVERSE_DATASET.get(name) for name in MODEL_GNS_NAMES} | {f"doe_{name}" for name in SHARED_GNS}
    if model_column(dataset) or dataset in feeds_chain:
        return MODEL_CHAIN_PRIORITY
    feeds_answer = set(INVERSE_DATASET.values()) | {f"doe_{name}" for name in DOE_NAMES}
    return ANSWER_PRIORITY if dataset in feeds_answer else 0


# The jobs whose time a DEM run costs: its settle and its collapse (its deck is a JSON written locally).
DEM_JOB_RULES = ("dem_packing", "dem_run")


# The longest path of all: a measured column's diagnosis decides the model whose GNS dataset is run
# and trained from scratch (diagnosis.smk, calibrated.smk); it goes before the base GNS's jobs.
MODEL_CHAIN_PRIORITY = 15
# A column's answer (calibrated.smk) and every job it waits on, below the model chain and above the
# jobs no answer waits on. A job's priority is at least that of any job waiting on it: a job of
# priority 0 that a chain waits on is started last, and the chain waits with it
# (docs/experiments/dag-wall-time.md).
ANSWER_PRIORITY = 10


def model_chain_priority(name):
    """Priority of the diagnosis and model jobs of measured column `name`: first where its model
    gets a GNS (MODEL_GNS_NAMES, calibrated.smk), else the answer's."""
    return MODEL_CHAIN_PRIORITY if name in MODEL_GNS_NAMES else ANSWER_PRIORITY


def route_priority(name, route):
    """Priority of route `route` of measured column `name` (its optimisation and its validation):
    the model chain's for the routes through the model's GNS (its own, and the base model's where
    one GNS runs both, SHARED_GNS), which cannot start before that GNS is trained, else the
    answer's, which waits on every route (calibrated.smk, inverse.smk, doe.smk)."""
    through_model_gns = route == "model-inverse" or (route == "base-inverse" and name in SHARED_GNS)
    return MODEL_CHAIN_PRIORITY if through_model_gns else ANSWER_PRIORITY


def gns_test_cases(dataset):
    """case_ids of a dataset's test split, in case_id order (gns.smk, runout.smk)."""
    return [row["case_id"] for row in dataset_cases(dataset) if row["split"] == "test"]


def inverse_gns_dataset(name):
    """The dataset whose GNS runs the base model's inverse design of measured column `name`: the
    inverse.dataset's, or with calibration.gns_shared the model's (SHARED_GNS)."""
    return f"calibrated_{name}" if name in SHARED_GNS else INVERSE_DATASET[name]


def inverse_gns(name, what):
    """model / metadata / evaluation file of the GNS that calibrates measured column `name` (inverse.smk)."""
    dataset = inverse_gns_dataset(name)
    return {
        "model": f"results/gns/{dataset}/train/model_best.pt",
        "metadata": f"results/datasets/{dataset}/metadata.json",
        "evaluation": f"results/gns/{dataset}/evaluation/summary.json",
    }[what]


def inverse_dem_metadata(name):
    """The metadata of the dataset whose column the DEM runs of measured column `name`'s base
    routes take (the start run, the validation, the BO on DEM: inverse.smk): inverse.dataset's,
    ready before the model's, whose GNS may run the base route (SHARED_GNS)."""
    return f"results/datasets/{INVERSE_DATASET[name]}/metadata.json"


def dem_job_benchmarks(dataset, case_ids):
    """Benchmark files of the DEM jobs (DEM_JOB_RULES) of `dataset`'s cases `case_ids`."""
    return [f"results/benchmarks/dem/{rule}/{dataset}/{c}.tsv" for rule in DEM_JOB_RULES for c in case_ids]


def gns_benchmarks(dataset):
    """{"gns_dataset": benchmark files of the DEM jobs of GNS dataset `dataset` (gns_dem_datasets)
    and of its metadata job, "gns_training": that of the training of its GNS}: what a GNS costs
    before any search on it."""
    runs = [
        f for d in gns_dem_datasets(dataset) for f in dem_job_benchmarks(d, [r["case_id"] for r in dataset_cases(d)])
    ]
    return {
        "gns_dataset": runs + [f"results/benchmarks/dataset/dataset/{dataset}.tsv"],
        "gns_training": [f"results/benchmarks/gns/gns_train/{dataset}.tsv"],
    }


def gns_dem_runs(dataset):
    """The DEM runs the GNS of `dataset` trains on (gns_dem_datasets)."""
    return sum(len(dataset_cases(d)) for d in gns_dem_datasets(dataset))


def inverse_benchmarks(name):
    """Benchmark files of every job each calibration route of `name` ran (the comparison's times; inverse.smk)."""
    files = {
        "start": [f"results/benchmarks/inverse/inverse_start/{name}.tsv"],
        **gns_benchmarks(inverse_gns_dataset(name)),
        "gns_validation": [f"results/benchmarks/inverse/inverse_validate/{name}.tsv"],
        "bayesopt": [f"results/benchmarks/inverse/inverse_bayesopt/{name}.tsv"],
    }
    if name in DOE_NAMES:
        files["doe"] = dem_job_benchmarks(f"doe_{name}", DOE_RUNS) + [
            f"results/benchmarks/doe/{rule}/{name}.tsv" for rule in ("doe_design", "doe_analyse")
        ]
        files["doe_validation"] = {m: [f"results/benchmarks/doe/doe_validate/{name}/{m}.tsv"] for m in DOE["validate"]}
    return files


def report_captions():
    """{output pattern: its caption file (relative to the working directory)} of every output
    registered with report(). The Markdown report (report.smk) puts the same caption under each
    figure, so a caption is written once, in workflow/report/<stem>.rst."""
    captions = {}
    for step in workflow.rules:
        for path in step.output:
            if is_flagged(path, "report") and get_flag_value(path, "report").caption is not None:
                caption = get_flag_value(path, "report").caption.get_path_or_uri(secret_free=True)
                captions[str(path)] = os.path.relpath(caption)
    return captions


def calibrated_routes(name):
    """{route key: the file holding its optimum} of every route the calibrated stage validates for
    measured column `name` (route keys: pipeline.calibrated.route_optimum; calibrated.smk)."""
    routes = {}
    if config["diagnosis"]["enabled"]:
        routes["diagnosis-base"] = f"results/diagnosis/{name}/diagnosis.json"
        if SCALING_CHECK:  # the contenders' fits: the diagnosis' own, and those of pairs
            routes["diagnosis-model"] = f"results/calibrated/{name}/contenders.json"
        elif CALIBRATION["model"] != "base" and "+" not in CALIBRATION["model"]:
            routes["diagnosis-model"] = routes["diagnosis-base"]
    if name in INVERSE_NAMES:
        routes["base-inverse"] = f"results/inverse/{name}/inverse.json"
        if INVERSE["bayesopt_budget"]:
            routes["base-bayesopt"] = f"results/inverse/{name}/bayesopt.json"
    if name in DOE_NAMES:
        routes.update({f"base-doe-{m}": f"results/doe/{name}/analysis.json" for m in DOE["models"]})
    if name in MODEL_GNS_NAMES:
        routes["model-inverse"] = f"results/calibrated/{name}/inverse.json"
    routes["model-doe"] = f"results/calibrated/{name}/doe.json"
    routes["model-doe-ff"] = f"results/calibrated/{name}/doe_full_factorial.json"
    routes["model-bayesopt"] = f"results/calibrated/{name}/bayesopt.json"
    return routes


def calibrated_cost(name, route):
    """{"files": benchmark files of the jobs route `route` of measured column `name` ran, "dem_runs":
    the DEM runs it spent (None: its own file says), for the model's GNS route "own_dem_runs": those
    of its own dataset}: the cost the report shows beside each route."""
    if route == "model-bayesopt":
        return {"files": [f"results/benchmarks/calibrated/calibrated_bayesopt/{name}.tsv"], "dem_runs": None}
    if route in ("base-inverse", "model-inverse"):
        base = inverse_benchmarks(name)  # the paper's GNS route: its dataset, training and start run
        files = base["gns_dataset"] + base["gns_training"] + base["start"]
        runs = gns_dem_runs(inverse_gns_dataset(name))  # each DEM run: its deck, packing and collapse
        if route == "base-inverse":
            return {"files": files + [f"results/benchmarks/inverse/inverse_design/{name}.tsv"], "dem_runs": runs}
        if name in SHARED_GNS:  # one GNS for both models: its dataset, training and the start run
            inverse = f"results/benchmarks/calibrated/calibrated_inverse/{name}.tsv"
            return {"files": files + [inverse], "dem_runs": runs, "own_dem_runs": runs}
        # a model's GNS warm-started from the base GNS also costs that GNS's dataset and training; from
        # scratch (the default) it borrows only the base route's start run (its first frames)
        borrowed_files, borrowed_runs = (files, runs) if CALIBRATION["gns_warm_start"] else (base["start"], 0)
        own = gns_benchmarks(f"calibrated_{name}")
        own_files = [
            *own["gns_dataset"],
            *own["gns_training"],
            f"results/benchmarks/calibrated/calibrated_inverse/{name}.tsv",
        ]
        cases = dataset_cases(f"calibrated_{name}")
        # the base GNS's runs are shared with the paper's route (and any column of its geometry): its own apart
        return {
            "files": borrowed_files + own_files,
            "dem_runs": borrowed_runs + len(cases),
            "own_dem_runs": len(cases),
        }
    if route.startswith("base-doe-"):
        doe = inverse_benchmarks(name)["doe"] if name in INVERSE_NAMES else []
        return {"files": doe, "dem_runs": None}
    if route == "base-bayesopt":
        return {"files": inverse_benchmarks(name)["bayesopt"], "dem_runs": None}
    # the diagnosis fits (the diagnosis job's time) and the model's DoE routes (each its own runs' time:
    # one job runs both designs): what their files say
    return {"files": [], "dem_runs": None}
