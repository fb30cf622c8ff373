# GNS stage (gns/): for every dataset in gns.datasets (default: all), train a graph-network
# simulator on its train split (best model on its valid split), roll it out on each test case
# from the case's first C frames, score the rollouts against the DEM, and write the report
# section results/report/gns.md. Outputs under results/gns/<dataset>/.
# Training resumes from results/gns/<dataset>/train/checkpoint_last.pt after a kill; that file is
# not a declared output, so a failed job does not delete it.
GNS = config["gns"]
GNS_THREADS = GNS["threads"]
# gns.datasets (checked in common.smk), each base dataset whose model's GNS takes its place
# (calibration.gns_shared: REPLACED_GNS) replaced by that model's dataset
GNS_DATASETS = list(
    dict.fromkeys(d for base in pipeline.config.gns_datasets(config) for d in REPLACED_GNS.get(base, [base]))
)

# gns_settings and gns_test_cases: common.smk


rule gns_train:
    input:
        metadata="results/datasets/{dataset}/metadata.json",
        init=lambda w: gns_init(w.dataset),  # warm start (a calibrated model's GNS)
    output:
        model="results/gns/{dataset}/train/model_best.pt",
        metrics=report(
            "results/gns/{dataset}/train/metrics.csv",
            caption="../report/train_metrics.rst",
            category="3. GNS",
            subcategory="{dataset}",
            labels={"result": "training log"},
        ),
        figure=report(
            "results/gns/{dataset}/train/loss_curve.png",
            caption="../report/loss_curve.rst",
            category="3. GNS",
            subcategory="{dataset}",
            labels={"result": "loss curve"},
        ),
    log:
        "results/logs/gns/gns_train/{dataset}.log",
    benchmark:
        "results/benchmarks/gns/gns_train/{dataset}.tsv"
    priority: lambda w: critical_priority(w.dataset)
    conda:
        "../envs/pipeline.yaml"
    threads: GNS_THREADS
    resources:
        runtime=240,
        mem_mb=4000,
    params:
        settings=lambda w: gns_settings(w.dataset),
        runout=RUNOUT,
    script:
        "../scripts/gns_train.py"


rule gns_rollout:
    input:
        model="results/gns/{dataset}/train/model_best.pt",
        metadata="results/datasets/{dataset}/metadata.json",
        dem="results/dem/{dataset}/trajectories/{case_id}.h5",
    output:
        "results/gns/{dataset}/rollouts/{case_id}.h5",
    log:
        "results/logs/gns/gns_rollout/{dataset}/{case_id}.log",
    benchmark:
        "results/benchmarks/gns/gns_rollout/{dataset}/{case_id}.tsv"
    priority: lambda w: critical_priority(w.dataset)
    conda:
        "../envs/pipeline.yaml"
    threads: GNS_THREADS
    resources:
        runtime=30,
        mem_mb=2000,
    script:
        "../scripts/gns_rollout.py"


rule gns_evaluate:
    input:
        dem=lambda w: expand(
            "results/dem/{dataset}/trajectories/{case_id}.h5", dataset=w.dataset, case_id=gns_test_cases(w.dataset)
        ),
        gns=lambda w: expand(
            "results/gns/{dataset}/rollouts/{case_id}.h5", dataset=w.dataset, case_id=gns_test_cases(w.dataset)
        ),
    output:
        summary="results/gns/{dataset}/evaluation/summary.json",
        metrics=report(
            "results/gns/{dataset}/evaluation/metrics.csv",
            caption="../report/evaluation_metrics.rst",
            category="3. GNS",
            subcategory="{dataset}",
            labels={"result": "test split, per case"},
        ),
        figure=report(
            "results/gns/{dataset}/evaluation/runout_curves.png",
            caption="../report/runout_curves.rst",
            category="3. GNS",
            subcategory="{dataset}",
            labels={"result": "test split, runout curves"},
        ),
    log:
        "results/logs/gns/gns_evaluate/{dataset}.log",
    benchmark:
        "results/benchmarks/gns/gns_evaluate/{dataset}.tsv"
    priority: lambda w: critical_priority(w.dataset)
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=30,
        mem_mb=2000,
    params:
        runout=RUNOUT,
    script:
        "../scripts/gns_evaluate.py"


rule gns_section:
    input:
        summaries=expand("results/gns/{dataset}/evaluation/summary.json", dataset=GNS_DATASETS),
        loss_curves=expand("results/gns/{dataset}/train/loss_curve.png", dataset=GNS_DATASETS),
        metrics=expand("results/gns/{dataset}/train/metrics.csv", dataset=GNS_DATASETS),
    output:
        "results/report/gns.md",
    log:
        "results/logs/gns/gns_section.log",
    benchmark:
        "results/benchmarks/gns/gns_section.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        datasets=GNS_DATASETS,
    script:
        "../scripts/gns_section.py"


FINAL_TARGETS += expand("results/gns/{dataset}/evaluation/summary.json", dataset=GNS_DATASETS)
REPORT_SECTIONS.append(("Graph-network simulator", "results/report/gns.md"))
