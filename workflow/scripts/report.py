"""Stitch the stage fragments and the time-per-stage table into results/report.md."""

import logging

from pipeline.report import assemble_report

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
sections = list(zip(snakemake.params.titles, snakemake.input.sections))
assemble_report(
    sections,
    snakemake.params.benchmarks,
    snakemake.output.report,
    snakemake.params.title,
    snakemake.output.time_figure,
    captions=snakemake.params.captions,
)
logging.info("report %s: %d sections", snakemake.output.report, len(sections))
