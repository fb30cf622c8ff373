"""The metadata JSON of the GNS dataset of a column's calibrated model."""

import logging

from pipeline.calibrated_gns import build_model_dataset

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
build_model_dataset(
    snakemake.input.model,
    snakemake.params.splits,
    snakemake.output[0],
    f"calibrated_{snakemake.wildcards.name}",
    snakemake.params.channel_width,
)
logging.info("wrote %s", snakemake.output[0])
