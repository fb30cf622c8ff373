"""The report's first section (results/report/calibrated.md) from every calibrated.json."""

import logging

from pipeline.calibrated import run_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
run_section(snakemake.input.results, snakemake.input.figures, snakemake.output[0])
logging.info("wrote %s", snakemake.output[0])
