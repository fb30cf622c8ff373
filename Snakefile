# The whole pipeline: config -> DEM datasets -> GNS -> calibration (DoE, inverse design) -> report.
# Each stage is one file in workflow/rules/; it appends its outputs to FINAL_TARGETS and its report
# fragment to REPORT_SECTIONS (both defined in common.smk). Add a stage: one include line below.
# The default config; a --configfile on the command line replaces it rather than merging into it.
if not workflow.overwrite_configfiles:

    configfile: "config/config.yaml"


# Snakemake rate-limits job starts (--max-jobs-per-timespan, default 100/1s) by waking its scheduler
# one timespan after every pass; each wake-up sets the next, and every finished job starts one more
# such chain: by the default DAG's end they kept Snakemake at 15-25% of a core, and its exit waits
# for the last one (benchmarks/scheduler_overhead.py). A local run has no queue to shield from a
# burst of submissions, so its scheduler runs without the limiter; a cluster executor keeps it.
onstart:
    if workflow.local_exec and hasattr(workflow.scheduler, "job_rate_limiter"):
        workflow.scheduler.job_rate_limiter = None


# Snakemake's HTML report (snakemake --report results/report.html): this description first, then
# every figure and table registered with report() in the rules, grouped by stage.
report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/dem.smk"
include: "workflow/rules/dataset.smk"
include: "workflow/rules/gns.smk"
include: "workflow/rules/doe.smk"
include: "workflow/rules/inverse.smk"
include: "workflow/rules/diagnosis.smk"
include: "workflow/rules/runout.smk"
include: "workflow/rules/calibrated.smk"
include: "workflow/rules/campaign.smk"
include: "workflow/rules/scale_ladder.smk"
# later stages go here, before report.smk (the report collects what they registered)
include: "workflow/rules/export.smk"
include: "workflow/rules/report.smk"


rule all:
    default_target: True
    input:
        FINAL_TARGETS,
        "results/report.md",
