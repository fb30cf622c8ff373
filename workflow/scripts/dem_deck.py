"""Write one case's deck (engine-neutral JSON) from its case-table row (params.row; a calibrated
model's case: and its model.json)."""

import logging

from pipeline.dem import write_deck

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
write_deck(dict(snakemake.params.row), snakemake.output[0], *snakemake.input.model)
logging.info("wrote %s", snakemake.output[0])
