# Inverse-design stage (pipeline/inverse.py, its GNS jobs pipeline/inverse_design.py; methods in calibration/inverse.py,
# compare.py, recovery.py). For every measured
# column named in inverse.measured: a DEM run at the start point (its first frames start every GNS
# rollout; its objective is the uncalibrated value), the GNS inverse design (L-BFGS-B, multi-start,
# posterior), a DEM validation run at the GNS optimum, Bayesian optimisation directly on DEM runs,
# and the comparison with the DoE (when the DoE calibrates the same column). For every dataset in
# inverse.recovery_datasets: recovery of synthetic DEM targets. Report: results/report/inverse.md.
# INVERSE, INVERSE_NAMES: common.smk.
INVERSE_RECOVERY = INVERSE["recovery_datasets"]
# BO on DEM is not bound to a GNS's trained range: it searches the paper's box unless told otherwise
INVERSE_BO_BOUNDS = [INVERSE["friction"] or [0.3, 0.9], INVERSE["restitution"] or [0.3, 0.9]]
# INVERSE_DATASET (common.smk): {name: the dataset whose GNS calibrates it}; inverse.measured,
# inverse.dataset (the column lies in that GNS's trained geometry) and inverse.recovery_datasets
# are checked there, before any job runs (pipeline.config.check_cross_keys). inverse_gns,
# inverse_dem_metadata and inverse_benchmarks: common.smk.


rule inverse_start:
    input:
        measured=lambda w: config["measured"][w.name],
        metadata=lambda w: inverse_dem_metadata(w.name),
    output:
        "results/inverse/{name}/start.h5",
    log:
        "results/logs/inverse/inverse_start/{name}.log",
    benchmark:
        "results/benchmarks/inverse/inverse_start/{name}.tsv"
    # on the longest path (the calibrated model's GNS inverse design starts from it) but ready long
    # before: without it the DEM jobs queued ahead of it held that path ~3 min in a timed default run
    priority: lambda w: model_chain_priority(w.name)
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=120,
        mem_mb=2000,
    params:
        start=INVERSE["start"],
        seed=INVERSE["seed"],
        runout=RUNOUT,
        dem=DEM_ENGINE,
    script:
        "../scripts/inverse_dem_run.py"


rule inverse_design:
    input:
        model=lambda w: inverse_gns(w.name, "model"),
        metadata=lambda w: inverse_gns(w.name, "metadata"),
        evaluation=lambda w: inverse_gns(w.name, "evaluation"),
        start="results/inverse/{name}/start.h5",
        measured=lambda w: config["measured"][w.name],
        doe_responses=lambda w: [f"results/doe/{w.name}/responses.csv"] if w.name in DOE_NAMES else [],
    output:
        result="results/inverse/{name}/inverse.json",
        paths=report(
            "results/inverse/{name}/paths.png",
            caption="../report/paths.rst",
            category="5. Inverse design",
            subcategory="{name}",
            labels={"result": "GNS inverse design paths"},
        ),
        deposits=report(
            "results/inverse/{name}/deposits.png",
            caption="../report/deposits.rst",
            category="5. Inverse design",
            subcategory="{name}",
            labels={"result": "GNS deposits"},
        ),
    log:
        "results/logs/inverse/inverse_design/{name}.log",
    benchmark:
        "results/benchmarks/inverse/inverse_design/{name}.tsv"
    # the optimisation of the base-inverse route: its priority is that route's (route_priority)
    priority: lambda w: route_priority(w.name, "base-inverse")
    conda:
        "../envs/pipeline.yaml"
    threads: INVERSE["threads"]
    resources:
        runtime=120,
        mem_mb=4000,
    params:
        settings=INVERSE,
        runout=RUNOUT,
    script:
        "../scripts/inverse_design.py"


rule inverse_validate:
    input:
        result="results/inverse/{name}/inverse.json",
        measured=lambda w: config["measured"][w.name],
        metadata=lambda w: inverse_dem_metadata(w.name),
    output:
        "results/inverse/{name}/validation.h5",
    log:
        "results/logs/inverse/inverse_validate/{name}.log",
    benchmark:
        "results/benchmarks/inverse/inverse_validate/{name}.tsv"
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=120,
        mem_mb=2000,
    params:
        seed=INVERSE["seed"],
        runout=RUNOUT,
        dem=DEM_ENGINE,
    script:
        "../scripts/inverse_dem_run.py"


rule inverse_bayesopt:
    input:
        measured=lambda w: config["measured"][w.name],
        metadata=lambda w: inverse_dem_metadata(w.name),
    output:
        result="results/inverse/{name}/bayesopt.json",
        figure=report(
            "results/inverse/{name}/bayesopt.png",
            caption="../report/bayesopt.rst",
            category="5. Inverse design",
            subcategory="{name}",
            labels={"result": "Bayesian optimisation on DEM"},
        ),
        best="results/inverse/{name}/bayesopt_best.h5",
    log:
        "results/logs/inverse/inverse_bayesopt/{name}.log",
    benchmark:
        "results/benchmarks/inverse/inverse_bayesopt/{name}.tsv"
    priority: lambda w: route_priority(w.name, "base-bayesopt")
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=600,
        mem_mb=2000,
    params:
        bounds=INVERSE_BO_BOUNDS,
        budget=INVERSE["bayesopt_budget"],
        seed=INVERSE["seed"],
        runout=RUNOUT,
        dem=DEM_ENGINE,
    script:
        "../scripts/inverse_bayesopt.py"


rule inverse_compare:
    input:
        measured=lambda w: config["measured"][w.name],
        result="results/inverse/{name}/inverse.json",
        validation="results/inverse/{name}/validation.h5",
        start="results/inverse/{name}/start.h5",
        bayesopt=lambda w: [f"results/inverse/{w.name}/bayesopt.json"] if INVERSE["bayesopt_budget"] else [],
        bayesopt_best=lambda w: [f"results/inverse/{w.name}/bayesopt_best.h5"] if INVERSE["bayesopt_budget"] else [],
        doe_validation=lambda w: (
            expand("results/doe/{name}/validation/{model}.h5", name=w.name, model=DOE["validate"])
            if w.name in DOE_NAMES
            else []
        ),
    output:
        table=report(
            "results/inverse/{name}/comparison.csv",
            caption="../report/comparison_table.rst",
            category="5. Inverse design",
            subcategory="{name}",
            labels={"result": "routes compared (table)"},
        ),
        figure=report(
            "results/inverse/{name}/comparison.png",
            caption="../report/comparison.rst",
            category="5. Inverse design",
            subcategory="{name}",
            labels={"result": "routes compared"},
        ),
        runout=report(
            "results/inverse/{name}/runout.png",
            caption="../report/inverse_runout.rst",
            category="5. Inverse design",
            subcategory="{name}",
            labels={"result": "runout of every route"},
        ),
    log:
        "results/logs/inverse/inverse_compare/{name}.log",
    benchmark:
        "results/benchmarks/inverse/inverse_compare/{name}.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        benchmarks=lambda w: inverse_benchmarks(w.name),
        dem_runs=lambda w: {"gns_dataset": gns_dem_runs(inverse_gns_dataset(w.name)), "doe": len(DOE_RUNS)},
        runout=RUNOUT,
    script:
        "../scripts/inverse_compare.py"


rule inverse_recovery:
    input:
        model="results/gns/{dataset}/train/model_best.pt",
        metadata="results/datasets/{dataset}/metadata.json",
        evaluation="results/gns/{dataset}/evaluation/summary.json",
    output:
        result="results/inverse_recovery/{dataset}/recovery.json",
        figure=report(
            "results/inverse_recovery/{dataset}/recovery.png",
            caption="../report/recovery.rst",
            category="5. Inverse design",
            subcategory="recovery on {dataset}",
            labels={"result": "parameter recovery"},
        ),
    log:
        "results/logs/inverse/inverse_recovery/{dataset}.log",
    benchmark:
        "results/benchmarks/inverse/inverse_recovery/{dataset}.tsv"
    conda:
        "../envs/pipeline.yaml"
    threads: INVERSE["threads"]
    resources:
        runtime=600,
        mem_mb=4000,
    params:
        settings=INVERSE,
        runout=RUNOUT,
        dem=DEM_ENGINE,
    script:
        "../scripts/inverse_recovery.py"


rule inverse_section:
    input:
        measured=[config["measured"][n] for n in INVERSE_NAMES],
        results=expand("results/inverse/{name}/inverse.json", name=INVERSE_NAMES),
        tables=expand("results/inverse/{name}/comparison.csv", name=INVERSE_NAMES),
        figures=expand(
            "results/inverse/{name}/{figure}.png",
            name=INVERSE_NAMES,
            figure=["paths", "deposits", "runout", "comparison"],
        ),
        bayesopt=expand("results/inverse/{name}/bayesopt.png", name=INVERSE_NAMES) if INVERSE["bayesopt_budget"] else [],
        recovery=expand("results/inverse_recovery/{dataset}/recovery.json", dataset=INVERSE_RECOVERY),
        recovery_figures=expand("results/inverse_recovery/{dataset}/recovery.png", dataset=INVERSE_RECOVERY),
    output:
        "results/report/inverse.md",
    log:
        "results/logs/inverse/inverse_section.log",
    benchmark:
        "results/benchmarks/inverse/inverse_section.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        names=INVERSE_NAMES,
        bayesopt=INVERSE["bayesopt_budget"] > 0,
    script:
        "../scripts/inverse_section.py"


if INVERSE_NAMES or INVERSE_RECOVERY:
    FINAL_TARGETS += expand("results/inverse/{name}/comparison.png", name=INVERSE_NAMES)
    FINAL_TARGETS += expand("results/inverse_recovery/{dataset}/recovery.png", dataset=INVERSE_RECOVERY)
    REPORT_SECTIONS.append(("Inverse design through the GNS and the comparison with DoE", "results/report/inverse.md"))
