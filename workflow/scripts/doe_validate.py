"""DEM validation run at one model's DoE optimum (trajectory HDF5, atomically)."""

import logging

from pipeline.doe import validate

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
validate(
    snakemake.input.analysis,
    snakemake.input.measured,
    snakemake.wildcards.doe_model,
    snakemake.params.case_fields,
    snakemake.params.dem,
    snakemake.params.runout,
    snakemake.output[0],
)
logging.info("wrote %s", snakemake.output[0])
