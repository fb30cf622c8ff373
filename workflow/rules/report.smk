# Report: every stage's section fragment (REPORT_SECTIONS) stitched into results/report.md, with
# the time per stage from the benchmark files. Input functions run after every .smk is parsed, so
# the report sees the sections of stages included after this file too.


rule report:
    input:
        sections=lambda w: [path for _, path in REPORT_SECTIONS],
        targets=lambda w: FINAL_TARGETS,
    output:
        report="results/report.md",
        time_figure="results/report/time_per_stage.png",
    log:
        "results/logs/report/report.log",
    benchmark:
        "results/benchmarks/report/report.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    params:
        titles=lambda w: [title for title, _ in REPORT_SECTIONS],
        title=config["report"]["title"],
        benchmarks="results/benchmarks",
    script:
        "../scripts/report.py"
