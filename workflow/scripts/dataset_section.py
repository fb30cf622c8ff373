"""The report section on the DEM datasets (results/report/dataset.md)."""

import logging

from pipeline.dataset_section import write_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
write_section(snakemake.input.metadata, snakemake.input.figures, snakemake.output[0])
logging.info("wrote %s", snakemake.output[0])
