"""GNS rollout of one test case from its first C frames (engine "gns" trajectory HDF5)."""

import logging

from pipeline.gns import rollout

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
rollout(snakemake.input.model, snakemake.input.dem, snakemake.output[0], snakemake.input.metadata, snakemake.threads)
logging.info("wrote %s", snakemake.output[0])
