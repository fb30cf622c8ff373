# Dataset stage: the trajectories of each named dataset -> metadata JSON (splits, normalisation
# statistics) -> summary figure + case table CSV -> report section. dataset_trajectories: common.smk.


rule dataset:
    input:
        trajectories=lambda w: [p for paths in dataset_trajectories(w.dataset).values() for p in paths],
        # with calibration.gns_shared, the base model's runs of the column join its model's dataset
        base=lambda w: [p for paths in shared_base_splits(w.dataset).values() for p in paths],
        model=lambda w: model_json(w.dataset),
    output:
        "results/datasets/{dataset}/metadata.json",
    log:
        "results/logs/dataset/dataset/{dataset}.log",
    benchmark:
        "results/benchmarks/dataset/dataset/{dataset}.tsv"
    priority: lambda w: critical_priority(w.dataset)
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=60,
        mem_mb=2000,
    params:
        splits=lambda w: dataset_trajectories(w.dataset),
        model_by_config=lambda w: dataset_cases(w.dataset)[0].get("model_by_config"),
        base_splits=lambda w: shared_base_splits(w.dataset),
    script:
        "../scripts/dataset.py"


rule dataset_summary:
    input:
        "results/datasets/{dataset}/metadata.json",
    output:
        figure=report(
            "results/datasets/{dataset}/summary.png",
            caption="../report/summary.rst",
            category="2. DEM datasets",
            subcategory="{dataset}",
            labels={"result": "cases and runout curves"},
        ),
        cases=report(
            "results/datasets/{dataset}/cases.csv",
            caption="../report/cases.rst",
            category="2. DEM datasets",
            subcategory="{dataset}",
            labels={"result": "case table"},
        ),
    log:
        "results/logs/dataset/dataset_summary/{dataset}.log",
    benchmark:
        "results/benchmarks/dataset/dataset_summary/{dataset}.tsv"
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=60,
        mem_mb=2000,
    params:
        rows=lambda w: dataset_cases(w.dataset),
        runout=RUNOUT,
    script:
        "../scripts/dataset_summary.py"


rule dataset_section:
    input:
        metadata=expand("results/datasets/{dataset}/metadata.json", dataset=DATASETS),
        figures=expand("results/datasets/{dataset}/summary.png", dataset=DATASETS),
        cases=expand("results/datasets/{dataset}/cases.csv", dataset=DATASETS),
    output:
        "results/report/dataset.md",
    log:
        "results/logs/dataset/dataset_section.log",
    benchmark:
        "results/benchmarks/dataset/dataset_section.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    script:
        "../scripts/dataset_section.py"


FINAL_TARGETS += expand("results/datasets/{dataset}/metadata.json", dataset=DATASETS)
REPORT_SECTIONS.append(("DEM datasets", "results/report/dataset.md"))
