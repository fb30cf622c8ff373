# DEM stage: case table -> deck -> settled packing -> collapse run -> trajectory HDF5 -> figure.
# One job per case and step; outputs under results/dem/<dataset>/.

# The settled packing comes from the builtin settling step for every engine, so all engines start
# from the same grains; dem_run hands it to the engine named by config dem.engine (dem.engines).
# A calibrated model's case (dataset calibrated_<name>) is a case of the model the diagnosis chose:
# its deck waits for that model.json (model_json, common.smk).


rule dem_deck:
    input:
        model=lambda w: model_json(w.dataset),
    output:
        "results/dem/{dataset}/decks/{case_id}.json",
    log:
        "results/logs/dem/dem_deck/{dataset}/{case_id}.log",
    benchmark:
        "results/benchmarks/dem/dem_deck/{dataset}/{case_id}.tsv"
    priority: lambda w: critical_priority(w.dataset)
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        row=case_row,
    script:
        "../scripts/dem_deck.py"


rule dem_packing:
    input:
        deck="results/dem/{dataset}/decks/{case_id}.json",
    output:
        "results/dem/{dataset}/packings/{case_id}.h5",
    log:
        "results/logs/dem/dem_packing/{dataset}/{case_id}.log",
    benchmark:
        "results/benchmarks/dem/dem_packing/{dataset}/{case_id}.tsv"
    priority: lambda w: critical_priority(w.dataset)
    conda:
        "../envs/pipeline.yaml"
    threads: config["dem"]["threads"]
    resources:
        runtime=lambda w, threads, attempt: dem_resources(w, "settle", threads, attempt)["runtime"],
        mem_mb=lambda w, threads, attempt: dem_resources(w, "settle", threads, attempt)["mem_mb"],
    script:
        "../scripts/dem_packing.py"


rule dem_run:
    input:
        deck="results/dem/{dataset}/decks/{case_id}.json",
        packing="results/dem/{dataset}/packings/{case_id}.h5",
    output:
        "results/dem/{dataset}/trajectories/{case_id}.h5",
    log:
        "results/logs/dem/dem_run/{dataset}/{case_id}.log",
    benchmark:
        "results/benchmarks/dem/dem_run/{dataset}/{case_id}.tsv"
    priority: lambda w: critical_priority(w.dataset)
    conda:
        "../envs/pipeline.yaml"
    threads: config["dem"]["threads"]
    resources:
        runtime=lambda w, threads, attempt: dem_resources(w, "collapse", threads, attempt)["runtime"],
        mem_mb=lambda w, threads, attempt: dem_resources(w, "collapse", threads, attempt)["mem_mb"],
    params:
        engine=config["dem"]["engine"],
        solvers=config["dem"]["solvers"],
        keep_work=config["dem"]["keep_work"],
        work_dir="results/dem/{dataset}/work/{case_id}",
    script:
        "../scripts/dem_run.py"


rule dem_figure:
    input:
        "results/dem/{dataset}/trajectories/{case_id}.h5",
    output:
        "results/dem/{dataset}/figures/{case_id}.png",
    log:
        "results/logs/dem/dem_figure/{dataset}/{case_id}.log",
    benchmark:
        "results/benchmarks/dem/dem_figure/{dataset}/{case_id}.tsv"
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=15,
        mem_mb=1000,
    params:
        runout=RUNOUT,
    script:
        "../scripts/dem_figure.py"


if config["dem"]["figures"]:
    # the datasets' cases: the DoE's, the ladder's and the calibrated models' runs have figures of their own
    FINAL_TARGETS += [
        f"results/dem/{row['dataset']}/figures/{row['case_id']}.png"
        for row in CASES.values()
        if row["dataset"] in DATASETS
    ]
