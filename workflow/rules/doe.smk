# DoE stage (doe/): for every measured column named in doe.measured, a full-factorial
# design over friction and restitution (7 x 7 + replicated centre by default) run in DEM through
# the DEM stage's own rules (case-table dataset "doe_<name>", case_id = run_id), the response-
# surface regression and ANOVA, a DEM validation run at each model's optimum, figures, and the
# report section results/report/doe.md. Outputs under results/doe/<name>/.
# DOE, DOE_NAMES (checked in common.smk: each a `measured` entry, no dataset named doe_<name>),
# DOE_DESIGN and DOE_RUNS: common.smk; the design runs are rows of its case table (doe_<name>).
import doe.design

DOE_CASE_FIELDS = {"size_scale": DOE["size_scale"], "duration_over_tstar": DOE["duration_over_tstar"]}


wildcard_constraints:
    doe_model=r"eq9|quadratic",


rule doe_design:
    input:
        measured=lambda w: config["measured"][w.name],
    output:
        report(
            "results/doe/{name}/design.csv",
            caption="../report/design.rst",
            category="4. DoE",
            subcategory="{name}",
            labels={"result": "design"},
        ),
    log:
        "results/logs/doe/doe_design/{name}.log",
    benchmark:
        "results/benchmarks/doe/doe_design/{name}.tsv"
    priority: lambda w: route_priority(w.name, "base-inverse")
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        doe=DOE,
    script:
        "../scripts/doe_design.py"


rule doe_analyse:
    input:
        design="results/doe/{name}/design.csv",
        measured=lambda w: config["measured"][w.name],
        trajectories=expand("results/dem/doe_{{name}}/trajectories/{run}.h5", run=DOE_RUNS),
    output:
        responses=report(
            "results/doe/{name}/responses.csv",
            caption="../report/responses.rst",
            category="4. DoE",
            subcategory="{name}",
            labels={"result": "responses"},
        ),
        analysis="results/doe/{name}/analysis.json",
        surface=report(
            "results/doe/{name}/response_surface.png",
            caption="../report/response_surface.rst",
            category="4. DoE",
            subcategory="{name}",
            labels={"result": "response surfaces"},
        ),
    log:
        "results/logs/doe/doe_analyse/{name}.log",
    benchmark:
        "results/benchmarks/doe/doe_analyse/{name}.tsv"
    priority: lambda w: route_priority(w.name, "base-inverse")
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=30,
        mem_mb=2000,
    params:
        doe=DOE,
        runout=RUNOUT,
    script:
        "../scripts/doe_analyse.py"


rule doe_validate:
    input:
        analysis="results/doe/{name}/analysis.json",
        measured=lambda w: config["measured"][w.name],
    output:
        "results/doe/{name}/validation/{doe_model}.h5",
    log:
        "results/logs/doe/doe_validate/{name}/{doe_model}.log",
    benchmark:
        "results/benchmarks/doe/doe_validate/{name}/{doe_model}.tsv"
    conda:
        "../envs/pipeline.yaml"
    threads: config["dem"]["threads"]
    resources:
        runtime=240,
        mem_mb=2000,
    params:
        case_fields=dict(DOE_CASE_FIELDS, seed=DOE["seed"]),
        runout=RUNOUT,
        dem=DEM_ENGINE,
    script:
        "../scripts/doe_validate.py"


rule doe_section:
    input:
        measured=[config["measured"][n] for n in DOE_NAMES],
        analysis=expand("results/doe/{name}/analysis.json", name=DOE_NAMES),
        responses=expand("results/doe/{name}/responses.csv", name=DOE_NAMES),
        surfaces=expand("results/doe/{name}/response_surface.png", name=DOE_NAMES),
        centre=expand(
            "results/dem/doe_{name}/trajectories/{run}.h5", name=DOE_NAMES, run=doe.design.centre_run_id(DOE_DESIGN)
        ),
        validation=expand("results/doe/{name}/validation/{doe_model}.h5", name=DOE_NAMES, doe_model=DOE["validate"]),
    output:
        section="results/report/doe.md",
        # one report() per column: its subcategory is the column's name (this rule has no wildcard)
        runout=[
            report(
                f"results/doe/{name}/runout.png",
                caption="../report/doe_runout.rst",
                category="4. DoE",
                subcategory=name,
                labels={"result": "runout before and after"},
            )
            for name in DOE_NAMES
        ],
    log:
        "results/logs/doe/doe_section.log",
    benchmark:
        "results/benchmarks/doe/doe_section.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        names=DOE_NAMES,
        models=DOE["validate"],
        runout=RUNOUT,
        benchmarks=lambda w: {
            n: [
                f"results/benchmarks/dem/{rule}/doe_{n}/{run}.tsv"
                for rule in ("dem_packing", "dem_run")
                for run in DOE_RUNS
            ]
            + [f"results/benchmarks/doe/doe_validate/{n}/{m}.tsv" for m in DOE["validate"]]
            for n in DOE_NAMES
        },
    script:
        "../scripts/doe_section.py"


if DOE_NAMES:
    FINAL_TARGETS += expand("results/doe/{name}/runout.png", name=DOE_NAMES)
    REPORT_SECTIONS.append(("Calibration by design of experiments (DoE)", "results/report/doe.md"))
