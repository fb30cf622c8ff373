# Runout-method study (pipeline/runout.py; statistics in dem/runout_study.py): every runout method
# of dem.runout read off the same DEM runs of the GNS test cases and the DoE design centres: packing
# scatter per phase, frame-to-frame flicker and the chaos floor, with the GNS rollouts where a case
# has one. The table in results/report/runout.md is the evidence for the configured `runout.method`.
RUNOUT_CASES = {f"{d} {c}": f"results/dem/{d}/trajectories/{c}.h5" for d in GNS_DATASETS for c in gns_test_cases(d)}
RUNOUT_CASES.update(
    {
        f"DoE {n} centre": f"results/dem/doe_{n}/trajectories/{doe.design.centre_run_id(DOE_DESIGN)}.h5"
        for n in DOE_NAMES
    }
)
RUNOUT_ROLLOUTS = {f"{d} {c}": f"results/gns/{d}/rollouts/{c}.h5" for d in GNS_DATASETS for c in gns_test_cases(d)}


rule runout_methods:
    input:
        trajectories=list(RUNOUT_CASES.values()),
        rollouts=list(RUNOUT_ROLLOUTS.values()),
    output:
        study="results/runout/methods.json",
        figure=report(
            "results/runout/methods.png",
            caption="../report/methods.rst",
            category="8. Runout methods",
            labels={"result": "runout of every packing, by method"},
        ),
        section="results/report/runout.md",
    log:
        "results/logs/runout/runout_methods.log",
    benchmark:
        "results/benchmarks/runout/runout_methods.tsv"
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=60,
        mem_mb=2000,
    params:
        labels=list(RUNOUT_CASES),
        rollouts=RUNOUT_ROLLOUTS,
        runout=RUNOUT,
    script:
        "../scripts/runout_methods.py"


if RUNOUT_CASES:
    FINAL_TARGETS.append("results/runout/methods.json")
    REPORT_SECTIONS.append(("How the runout is read: the methods compared", "results/report/runout.md"))
