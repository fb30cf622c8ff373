# ParaView export (dem/vtk.py, pipeline/export.py; config `export_vtk`, off by default): trajectories
# as ParaView time series (<name>.pvd + one .vtu point file per frame). Any trajectory HDF5 under
# results/ exports on request to results/vtk/<its path without .h5>/ (rule export_vtk, e.g.
# `bash run.sh main results/vtk/dem/quartz_multiple/trajectories/case_000`); with export_vtk: true
# the DAG exports every GNS test-split rollout and the DEM run of the same case, the DoE and GNS
# inverse-design DEM validations, and the calibrated model's answer on its validation packings
# (rerun: the validation keeps only its runout curves).
EXPORT_VTK = config["export_vtk"]
# The GNS datasets whose test rollouts are exported: the base GNSs and the calibrated models' GNSs.
EXPORT_GNS_DATASETS = list(dict.fromkeys(GNS_DATASETS + [f"calibrated_{n}" for n in MODEL_GNS_NAMES]))


rule export_vtk:
    input:
        "results/{path}.h5",
    output:
        directory("results/vtk/{path}"),
    log:
        "results/logs/export/export_vtk/{path}.log",
    benchmark:
        "results/benchmarks/export/export_vtk/{path}.tsv"
    wildcard_constraints:
        path=r"(?!vtk/|calibrated/)[A-Za-z0-9_\-/]+",
    conda:
        "../envs/pipeline.yaml"
    resources:
        runtime=30,
        mem_mb=2000,
    script:
        "../scripts/export_vtk.py"


rule export_calibrated_vtk:
    input:
        calibrated="results/calibrated/{name}/calibrated.json",
        model="results/calibrated/{name}/model.json",
        measured=lambda w: config["measured"][w.name],
    output:
        directory("results/vtk/calibrated/{name}"),
    log:
        "results/logs/export/export_calibrated_vtk/{name}.log",
    benchmark:
        "results/benchmarks/export/export_calibrated_vtk/{name}.tsv"
    wildcard_constraints:
        name=r"[A-Za-z0-9_\-]+",
    conda:
        "../envs/pipeline.yaml"
    threads: config["dem"]["threads"]
    resources:
        runtime=60,
        mem_mb=2000,
    params:
        channel_width=CHANNEL_WIDTH,
        dem=DEM_ENGINE,
    script:
        "../scripts/export_calibrated_vtk.py"


if EXPORT_VTK:
    for dataset in EXPORT_GNS_DATASETS:
        for case_id in gns_test_cases(dataset):
            FINAL_TARGETS += [
                f"results/vtk/gns/{dataset}/rollouts/{case_id}",
                f"results/vtk/dem/{dataset}/trajectories/{case_id}",
            ]
    FINAL_TARGETS += expand("results/vtk/doe/{name}/validation/{model}", name=DOE_NAMES, model=DOE["validate"])
    FINAL_TARGETS += expand("results/vtk/inverse/{name}/validation", name=INVERSE_NAMES)
    FINAL_TARGETS += expand("results/vtk/calibrated/{name}", name=CALIBRATED_NAMES)
