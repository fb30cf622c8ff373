# Shared by every stage: the validated config, the case table, and the two lists each stage
# appends to. Logic lives in pipeline/config.py (validation) and dem/grid.py (the case table);
# this file only calls them.
from pathlib import Path

import dem.grid
import dem.runout
import pipeline.config
from snakemake.utils import min_version

min_version("9.0")

# Fails before any job runs, naming the key and what it allows; fills schema defaults.
config.update(pipeline.config.validate_config(config, Path(workflow.basedir, "workflow/schemas/config.schema.yaml")))

# The case table, built once: {case_key: row}, case_key = "<dataset>/<case_id>".
# A row holds every CollapseCase field of the case plus dataset, case_id and split.
CASES = dem.grid.case_table(config)
DATASETS = sorted(config["datasets"])
# Keys that name another key's entries (gns.datasets, doe.measured, inverse.*: a dataset, a
# `measured` entry, a GNS) checked once, before any job runs. On the way it resolves the dataset
# whose GNS calibrates each inverse.measured column: {name: dataset} (inverse.smk).
INVERSE_DATASET = pipeline.config.check_cross_keys(config, CASES)
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
    """Rows of one dataset, in case_id order."""
    return [row for key, row in CASES.items() if row["dataset"] == dataset]
