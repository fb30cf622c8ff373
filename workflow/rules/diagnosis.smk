# Discrepancy diagnosis (calibration/diagnosis.py). For every entry of `measured`: DEM
# design runs of the base model and of the base model plus each candidate mechanism (the library,
# builtin engine, coarse-grained), then the diagnosis (emulator fits, DEM scoring at the optima,
# residual structure, the verdict), its figures, and the report section
# results/report/diagnosis.md. Outputs under results/diagnosis/<name>/.
import calibration.diagnosis

DIAGNOSIS = config["diagnosis"]
DIAGNOSIS_NAMES = sorted(config["measured"]) if DIAGNOSIS["enabled"] else []
# the design runs depend on these settings only: changing a decision threshold reuses them
DIAGNOSIS_LIBRARY = {k: DIAGNOSIS[k] for k in calibration.diagnosis.LIBRARY_SETTINGS}


rule diagnosis_library:
    input:
        measured=lambda w: config["measured"][w.name],
    output:
        "results/diagnosis/{name}/library.npz",
    log:
        "results/logs/diagnosis/diagnosis_library/{name}.log",
    benchmark:
        "results/benchmarks/diagnosis/diagnosis_library/{name}.tsv"
    priority: lambda w: model_chain_priority(w.name)
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=240,
        mem_mb=2000,
    params:
        settings=DIAGNOSIS_LIBRARY,
        runout=RUNOUT,
    script:
        "../scripts/diagnosis_library.py"


rule diagnosis:
    input:
        measured=lambda w: config["measured"][w.name],
        library="results/diagnosis/{name}/library.npz",
    output:
        diagnosis="results/diagnosis/{name}/diagnosis.json",
        residuals=report(
            "results/diagnosis/{name}/residuals.png",
            caption="../report/residuals.rst",
            category="6. Diagnosis",
            subcategory="{name}",
            labels={"result": "residuals"},
        ),
        candidates=report(
            "results/diagnosis/{name}/candidates.png",
            caption="../report/candidates.rst",
            category="6. Diagnosis",
            subcategory="{name}",
            labels={"result": "candidate mechanisms"},
        ),
    log:
        "results/logs/diagnosis/diagnosis/{name}.log",
    benchmark:
        "results/benchmarks/diagnosis/diagnosis/{name}.tsv"
    priority: lambda w: model_chain_priority(w.name)
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=240,
        mem_mb=2000,
    params:
        settings=DIAGNOSIS,
        runout=RUNOUT,
    script:
        "../scripts/diagnosis.py"


rule diagnosis_section:
    input:
        expand("results/diagnosis/{name}/diagnosis.json", name=DIAGNOSIS_NAMES),
    output:
        "results/report/diagnosis.md",
    log:
        "results/logs/diagnosis/diagnosis_section.log",
    benchmark:
        "results/benchmarks/diagnosis/diagnosis_section.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        names=DIAGNOSIS_NAMES,
    script:
        "../scripts/diagnosis_section.py"


if DIAGNOSIS_NAMES:
    FINAL_TARGETS += expand("results/diagnosis/{name}/diagnosis.json", name=DIAGNOSIS_NAMES)
    REPORT_SECTIONS.append(("What the simulation gets wrong: diagnosis", "results/report/diagnosis.md"))
