# The calibrated model (calibration/calibrated.py): for every entry of `measured`, the
# model (calibration.model; auto: the diagnosis' answer, read from its diagnosis.json when the job
# runs, so a new measured curve needs no hand edit), its parameters by the diagnosis' fit and by
# Bayesian optimisation on DEM runs, every optimum validated on several packings. The report's first
# section, results/report/calibrated.md. Outputs under results/calibrated/<name>/.
# CALIBRATION, CALIBRATED_NAMES, CHANNEL_WIDTH: common.smk. The GNS route of the model, for every
# column with a base-model GNS (MODEL_GNS_NAMES, common.smk): a GNS dataset "calibrated_<name>" of
# the case table, whose case ids and splits are known now and whose parameters come from
# model.json when its jobs run (dataset_cases, gns_settings, gns_init: common.smk).


# Under auto (SCALING_CHECK, common.smk), the diagnosis' contenders (every model it scored in the DEM,
# at its fit, and pairs of its mechanisms fitted here) predicted across aspect ratios and held against
# the experimental scaling of dry column collapse, so that the model is chosen by what it predicts as
# well as by the one measured curve (calibration/contenders.py).


rule calibrated_contenders:
    input:
        measured=lambda w: config["measured"][w.name],
        diagnosis="results/diagnosis/{name}/diagnosis.json",
    output:
        result="results/calibrated/{name}/contenders.json",
        figure=report(
            "results/calibrated/{name}/contenders.png",
            caption="../report/contenders.rst",
            category="1. The answer",
            subcategory="{name}",
            labels={"result": "4. the contenders across aspect ratios"},
        ),
    log:
        "results/logs/calibrated/calibrated_contenders/{name}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated_contenders/{name}.tsv"
    priority: lambda w: model_chain_priority(w.name)
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=120,
        mem_mb=2000,
    params:
        settings=CALIBRATION,
        diagnosis=config["diagnosis"],
        runout=RUNOUT,
        dem=DEM_ENGINE,
    script:
        "../scripts/calibrated_contenders.py"


# Which model each column is calibrated as: the config's, or (auto) the diagnosis' answer, written
# once per column; every job of the stage reads it, so a new measured curve needs no hand edit.
rule calibrated_model:
    input:
        measured=lambda w: config["measured"][w.name],
        diagnosis=lambda w: (f"results/diagnosis/{w.name}/diagnosis.json" if config["diagnosis"]["enabled"] else []),
        # a campaign measures several aspect ratios itself: no contenders across a
        contenders=lambda w: (
            f"results/calibrated/{w.name}/contenders.json" if SCALING_CHECK and w.name in CALIBRATED_NAMES else []
        ),
    output:
        "results/calibrated/{name}/model.json",
    log:
        "results/logs/calibrated/calibrated_model/{name}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated_model/{name}.tsv"
    priority: lambda w: model_chain_priority(w.name)
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        model=CALIBRATION["model"],
        channel_width=CHANNEL_WIDTH,
        box=CALIBRATION["box"],
        plausible_ranges=CALIBRATION["plausible_ranges"],
    script:
        "../scripts/calibrated_model.py"


# The DoE routes: a face-centred central composite design over the model's parameters in DEM, the
# quadratic response surface and its ANOVA (doe/); and the 3-level full factorial from the same runs
# and the grid points the CCD lacks (three parameters: 30 runs, the GNS route's cost).
rule calibrated_doe:
    input:
        measured=lambda w: config["measured"][w.name],
        model="results/calibrated/{name}/model.json",
    output:
        result="results/calibrated/{name}/doe.json",
        responses=report(
            "results/calibrated/{name}/doe_responses.csv",
            caption="../report/doe_responses.rst",
            category="7. Calibrated model",
            subcategory="{name}",
            labels={"result": "DoE responses"},
        ),
        figure=report(
            "results/calibrated/{name}/doe_surface.png",
            caption="../report/doe_surface.rst",
            category="7. Calibrated model",
            subcategory="{name}",
            labels={"result": "DoE response surface"},
        ),
        full_factorial="results/calibrated/{name}/doe_full_factorial.json",
        full_factorial_figure=report(
            "results/calibrated/{name}/doe_full_factorial_surface.png",
            caption="../report/doe_surface.rst",
            category="7. Calibrated model",
            subcategory="{name}",
            labels={"result": "DoE response surface, 3-level full factorial"},
        ),
    log:
        "results/logs/calibrated/calibrated_doe/{name}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated_doe/{name}.tsv"
    priority: ANSWER_PRIORITY
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
        "../scripts/calibrated_doe.py"


# The Bayesian optimisation route: DEM runs over all the model's parameters (calibration.budget).
rule calibrated_bayesopt:
    input:
        measured=lambda w: config["measured"][w.name],
        model="results/calibrated/{name}/model.json",
    output:
        result="results/calibrated/{name}/bayesopt.json",
        figure=report(
            "results/calibrated/{name}/bayesopt.png",
            caption="../report/bayesopt.rst",
            category="7. Calibrated model",
            subcategory="{name}",
            labels={"result": "Bayesian optimisation on DEM"},
        ),
    log:
        "results/logs/calibrated/calibrated_bayesopt/{name}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated_bayesopt/{name}.tsv"
    priority: ANSWER_PRIORITY
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
        "../scripts/calibrated_bayesopt.py"


# The GNS route: the model's GNS dataset calibrated_<name> (rows of the case table, on the column of
# the base GNS's dataset) is run by the DEM stage's rules and built by the dataset stage's, each
# reading model.json (model_json, common.smk).


# The model's GNS is trained, rolled out and scored by the GNS stage's own rules (gns.smk) on the
# dataset calibrated_<name>; the inverse design then runs over all of the model's parameters.
rule calibrated_inverse:
    input:
        model="results/calibrated/{name}/model.json",
        gns="results/gns/calibrated_{name}/train/model_best.pt",
        metadata="results/datasets/calibrated_{name}/metadata.json",
        evaluation="results/gns/calibrated_{name}/evaluation/summary.json",
        start="results/inverse/{name}/start.h5",
        # further packings of the column: the objective is of their mean L* (calibration.start_packings)
        packings=lambda w: expand(
            "results/dem/calibrated_{name}/trajectories/{case_id}.h5",
            name=w.name,
            case_id=pipeline.calibrated_gns.start_packing_cases(CALIBRATION),
        ),
        measured=lambda w: config["measured"][w.name],
        # the dataset's DEM runs: does the GNS respond to each parameter as they do (calibration.sensitivity)
        dataset=lambda w: [p for paths in dataset_trajectories(f"calibrated_{w.name}").values() for p in paths],
    output:
        result="results/calibrated/{name}/inverse.json",
        paths=report(
            "results/calibrated/{name}/inverse_paths.png",
            caption="../report/inverse_paths.rst",
            category="7. Calibrated model",
            subcategory="{name}",
            labels={"result": "GNS inverse design paths"},
        ),
        deposits=report(
            "results/calibrated/{name}/inverse_deposits.png",
            caption="../report/inverse_deposits.rst",
            category="7. Calibrated model",
            subcategory="{name}",
            labels={"result": "GNS deposits"},
        ),
        sensitivity=report(
            "results/calibrated/{name}/inverse_sensitivity.png",
            caption="../report/inverse_sensitivity.rst",
            category="7. Calibrated model",
            subcategory="{name}",
            labels={"result": "does the GNS see each parameter"},
        ),
    log:
        "results/logs/calibrated/calibrated_inverse/{name}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated_inverse/{name}.tsv"
    priority: MODEL_CHAIN_PRIORITY
    conda:
        "../envs/pipeline.yaml"
    threads: INVERSE["threads"]
    resources:
        runtime=120,
        mem_mb=4000,
    params:
        settings=INVERSE,
        calibration=CALIBRATION,
        channel_width=CHANNEL_WIDTH,
        runout=RUNOUT,
    script:
        "../scripts/calibrated_inverse.py"


# Every route's optimum validated on calibration.validation_packings packings, one job per route
# (route keys: calibrated_routes in common.smk), as soon as that route has its answer.
rule calibrated_validate:
    input:
        measured=lambda w: config["measured"][w.name],
        model="results/calibrated/{name}/model.json",
        source=lambda w: calibrated_routes(w.name)[w.route],
    output:
        "results/calibrated/{name}/validation/{route}.json",
    log:
        "results/logs/calibrated/calibrated_validate/{name}/{route}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated_validate/{name}/{route}.tsv"
    priority: lambda w: route_priority(w.name, w.route)
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=120,
        mem_mb=2000,
    params:
        settings=CALIBRATION,
        diagnosis=config["diagnosis"],
        runout=RUNOUT,
        dem=DEM_ENGINE,
        cost=lambda w: calibrated_cost(w.name, w.route),
    script:
        "../scripts/calibrated_validate.py"


# The answer: the model's best validated route, validated again one size_scale finer, and its predictions.
rule calibrated:
    input:
        measured=lambda w: config["measured"][w.name],
        model="results/calibrated/{name}/model.json",
        validations=lambda w: expand(
            "results/calibrated/{name}/validation/{route}.json", name=w.name, route=list(calibrated_routes(w.name))
        ),
        diagnosis=lambda w: (f"results/diagnosis/{w.name}/diagnosis.json" if config["diagnosis"]["enabled"] else []),
    output:
        result="results/calibrated/{name}/calibrated.json",
        figure=report(
            "results/calibrated/{name}/calibrated.png",
            caption="../report/calibrated.rst",
            category="1. The answer",
            subcategory="{name}",
            labels={"result": "2. validated runout curves"},
        ),
        prediction=report(
            "results/calibrated/{name}/prediction.png",
            caption="../report/prediction.rst",
            category="1. The answer",
            subcategory="{name}",
            labels={"result": "3. prediction across aspect ratios"},
        ),
        scales=report(
            "results/calibrated/{name}/scales.png",
            caption="../report/scales.rst",
            category="1. The answer",
            subcategory="{name}",
            labels={"result": "4. the answer across grain sizes"},
        ),
    log:
        "results/logs/calibrated/calibrated/{name}.log",
    benchmark:
        "results/benchmarks/calibrated/calibrated/{name}.tsv"
    priority: ANSWER_PRIORITY
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
        scales=expand("results/calibrated/{name}/scales.png", name=CALIBRATED_NAMES),
        doe=expand("results/calibrated/{name}/doe_surface.png", name=CALIBRATED_NAMES),
        doe_full_factorial=expand("results/calibrated/{name}/doe_full_factorial_surface.png", name=CALIBRATED_NAMES),
        inverse=expand("results/calibrated/{name}/inverse_paths.png", name=MODEL_GNS_NAMES),
        sensitivity=expand("results/calibrated/{name}/inverse_sensitivity.png", name=MODEL_GNS_NAMES),
        bayesopt=expand("results/calibrated/{name}/bayesopt.png", name=CALIBRATED_NAMES),
        gns=expand(
            "results/gns/calibrated_{name}/{figure}",
            name=MODEL_GNS_NAMES,
            figure=["train/loss_curve.png", "evaluation/runout_curves.png"],
        ),
    output:
        section="results/report/calibrated.md",
        # the answer in a few lines per column, the report's first page (workflow/report/workflow.rst)
        answers=[
            report(
                f"results/report/answer_{name}.html",
                caption="../report/answer.rst",
                category="1. The answer",
                subcategory=name,
                labels={"result": "1. the answer"},
            )
            for name in CALIBRATED_NAMES
        ],
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
    FINAL_TARGETS += expand("results/report/answer_{name}.html", name=CALIBRATED_NAMES)
    # the answer to the user's question comes first
    REPORT_SECTIONS.insert(0, ("The calibrated model", "results/report/calibrated.md"))
