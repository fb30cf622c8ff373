# Scale ladder (dem/scale_ladder.py; stage layer pipeline/scale_ladder.py): one column and
# parameter set (config scale_ladder) run at every size_scale of scale_ladder.size_scales on
# scale_ladder.packings packings each, through the DEM stage's own rules (case-table dataset
# "scale_ladder", case_id scale<s>_packing<k>: their SLURM requests scale with the grains), then read
# by the configured runout method: L*(t/t*), the final deposit and the cost per run against
# size_scale. Outputs under results/scale_ladder/. Off while size_scales is empty.
import dem.scale_ladder

# checked in common.smk (each run a valid case, the size guard at the coarsest scale, the dataset
# name free); the runs are rows of its case table, so dem_deck/dem_packing/dem_run build them
LADDER_ROWS = dataset_cases(dem.scale_ladder.DATASET)


rule scale_ladder:
    input:
        trajectories=[f"results/dem/{r['dataset']}/trajectories/{r['case_id']}.h5" for r in LADDER_ROWS],
        packings=[f"results/dem/{r['dataset']}/packings/{r['case_id']}.h5" for r in LADDER_ROWS],
    output:
        summary="results/scale_ladder/summary.json",
        figure=report(
            "results/scale_ladder/ladder.png",
            caption="../report/scale_ladder.rst",
            category="2. DEM datasets",
            subcategory="scale ladder",
            labels={"result": "runout against grain size"},
        ),
        section="results/report/scale_ladder.md",
    log:
        "results/logs/scale_ladder/scale_ladder.log",
    benchmark:
        "results/benchmarks/scale_ladder/scale_ladder.tsv"
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=30,
        mem_mb=2000,
    params:
        runout=RUNOUT,
    script:
        "../scripts/scale_ladder.py"


if LADDER_ROWS:
    FINAL_TARGETS.append("results/scale_ladder/summary.json")
    REPORT_SECTIONS.append(("How the runout depends on grain size: the scale ladder", "results/report/scale_ladder.md"))
