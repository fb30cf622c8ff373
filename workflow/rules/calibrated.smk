# The calibrated model (calibration/calibrated.py, issue 15): for every entry of `measured`, the
# model (calibration.model; auto: the diagnosis' answer, read from its diagnosis.json when the job
# runs, so a new measured curve needs no hand edit), its parameters by the diagnosis' fit and by
# Bayesian optimisation on DEM runs, every optimum validated on several packings. The report's first
# section, results/report/calibrated.md. Outputs under results/calibrated/<name>/.
CALIBRATION = config["calibration"]
CALIBRATED_NAMES = sorted(config["measured"]) if CALIBRATION["enabled"] else []


rule calibrated:
    input:
        measured=lambda w: config["measured"][w.name],
        diagnosis=lambda w: (f"results/diagnosis/{w.name}/diagnosis.json" if config["diagnosis"]["enabled"] else []),
        # the paper's base-model routes, validated on the same packings beside the calibrated model
        inverse=lambda w: [f"results/inverse/{w.name}/inverse.json"] if w.name in INVERSE_NAMES else [],
        bayesopt=lambda w: (
            [f"results/inverse/{w.name}/bayesopt.json"]
            if w.name in INVERSE_NAMES and INVERSE["bayesopt_budget"]
            else []
        ),
        doe=lambda w: [f"results/doe/{w.name}/analysis.json"] if w.name in DOE_NAMES else [],
    output:
        result="results/calibrated/{name}/calibrated.json",
        figure="results/calibrated/{name}/calibrated.png",
        prediction="results/calibrated/{name}/prediction.png",
    log:
        "results/logs/calibrated/calibrated/{name}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated/{name}.tsv"
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=240,
        mem_mb=2000,
    params:
        settings=CALIBRATION,
        diagnosis=config["diagnosis"],
        runout=RUNOUT,
        dem=DEM_ENGINE,
    script:
        "../scripts/calibrated.py"


rule calibrated_section:
    input:
        results=expand("results/calibrated/{name}/calibrated.json", name=CALIBRATED_NAMES),
        figures=expand("results/calibrated/{name}/calibrated.png", name=CALIBRATED_NAMES),
        predictions=expand("results/calibrated/{name}/prediction.png", name=CALIBRATED_NAMES),
    output:
        "results/report/calibrated.md",
    log:
        "results/logs/calibrated/calibrated_section.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated_section.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    script:
        "../scripts/calibrated_section.py"


if CALIBRATED_NAMES:
    FINAL_TARGETS += expand("results/calibrated/{name}/calibrated.json", name=CALIBRATED_NAMES)
    # the answer to the user's question comes first
    REPORT_SECTIONS.insert(0, ("The calibrated model", "results/report/calibrated.md"))
