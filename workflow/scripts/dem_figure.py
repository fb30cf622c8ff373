"""Snapshots and runout curve of one case's collapse."""

import logging

from pipeline.dem import draw_case

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
draw_case(snakemake.input[0], snakemake.output[0], snakemake.params.runout)
logging.info("figure %s", snakemake.output[0])
