"""Write the DoE design table of one measured column (checked against its geometry)."""

import logging

from pipeline.doe import design

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
design(snakemake.input.measured, snakemake.params.doe, snakemake.output[0])
logging.info("wrote %s", snakemake.output[0])
