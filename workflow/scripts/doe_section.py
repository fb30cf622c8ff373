"""The DoE report section (results/report/doe.md) and the runout before/after figure per column."""

import logging

from pipeline.doe_section import write_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
write_section(
    snakemake.params.names,
    snakemake.input.measured,
    snakemake.input.analysis,
    snakemake.input.centre,
    snakemake.input.validation,
    snakemake.output.runout,
    snakemake.params.benchmarks,
    snakemake.output.section,
    runout=snakemake.params.runout,
)
logging.info("wrote %s", snakemake.output.section)
