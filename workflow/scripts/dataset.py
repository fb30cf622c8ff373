"""Build one dataset's metadata JSON (splits, normalisation statistics) from its trajectories (and,
for a calibrated model's GNS dataset, its model.json or its first row's model_by_config)."""

import logging

from pipeline.dataset import build

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
build(
    snakemake.params.splits,
    snakemake.output[0],
    snakemake.wildcards.dataset,
    *snakemake.input.model,
    model_by_config=snakemake.params.model_by_config,
    base_splits=snakemake.params.base_splits,
)
logging.info("wrote %s", snakemake.output[0])
