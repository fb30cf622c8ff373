# Dataset stage: the trajectories of each named dataset -> metadata JSON (splits, normalisation
# statistics) -> summary figure + case table CSV -> report section.


def dataset_trajectories(dataset):
    """{split: [trajectory paths]} of a dataset, from the case table."""
    splits = {"train": [], "valid": [], "test": []}
    for row in dataset_cases(dataset):
        splits[row["split"]].append(f"results/dem/{dataset}/trajectories/{row['case_id']}.h5")
    return splits


rule dataset:
    input:
        lambda w: [p for paths in dataset_trajectories(w.dataset).values() for p in paths],
    output:
        "results/datasets/{dataset}/metadata.json",
    params:
        splits=lambda w: dataset_trajectories(w.dataset),
    log:
        "results/logs/dataset/dataset/{dataset}.log",
    benchmark:
        "results/benchmarks/dataset/dataset/{dataset}.tsv"
    resources:
        runtime=60,
        mem_mb=2000,
    script:
        "../scripts/dataset.py"


rule dataset_summary:
    input:
        "results/datasets/{dataset}/metadata.json",
    output:
        figure="results/datasets/{dataset}/summary.png",
        cases="results/datasets/{dataset}/cases.csv",
    params:
        rows=lambda w: dataset_cases(w.dataset),
        runout=RUNOUT,
    log:
        "results/logs/dataset/dataset_summary/{dataset}.log",
    benchmark:
        "results/benchmarks/dataset/dataset_summary/{dataset}.tsv"
    resources:
        runtime=60,
        mem_mb=2000,
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
    script:
        "../scripts/dataset_section.py"


FINAL_TARGETS += expand("results/datasets/{dataset}/metadata.json", dataset=DATASETS)
REPORT_SECTIONS.append(("DEM datasets", "results/report/dataset.md"))
