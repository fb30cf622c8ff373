"""One DEM case of the GNS dataset of a column's calibrated model (every model parameter varied)."""

import logging

from pipeline.calibrated_gns import run_model_case

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
run_model_case(
    snakemake.input.model,
    dict(snakemake.params.template),
    snakemake.wildcards.case_id,
    snakemake.output[0],
    snakemake.params.settings,
    snakemake.params.channel_width,
    dem=snakemake.params.dem,
)
logging.info("wrote %s", snakemake.output[0])
