# Report: every stage's section fragment (REPORT_SECTIONS) stitched into results/report.md, with
# the time per stage from the benchmark files. Input functions run after every .smk is parsed, so
# the report sees the sections of stages included after this file too. Each figure gets the
# caption its rule registers with report() for Snakemake's HTML report (report_captions, common.smk;
# `snakemake --report results/report.html`), so a caption is written once.


rule report:
    input:
        sections=lambda w: [path for _, path in REPORT_SECTIONS],
        targets=lambda w: FINAL_TARGETS,
        captions=lambda w: sorted(set(report_captions().values())),
    output:
        report="results/report.md",
        time_figure=report(
            "results/report/time_per_stage.png",
            caption="../report/time_per_stage.rst",
            category="9. Time",
            labels={"result": "time per stage"},
        ),
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
        # the figures' captions, the HTML report's own (common.smk): {output pattern: caption file}
        captions=lambda w: report_captions(),
    script:
        "../scripts/report.py"
