"""The diagnosis report section (results/report/diagnosis.md) from every diagnosis.json."""

import logging

from pipeline.diagnosis_section import run_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
results = run_section(snakemake.params.names, snakemake.input, snakemake.output[0])
logging.info("wrote %s (%d data sets)", snakemake.output[0], len(results))
