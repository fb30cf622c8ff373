"""One calibration route's optimum of one measured column validated on several packings."""

import logging

from pipeline.calibrated import run_validation

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
result = run_validation(
    snakemake.wildcards.route,
    snakemake.input.source,
    snakemake.input.model,
    snakemake.input.measured,
    snakemake.output[0],
    snakemake.params.settings,
    snakemake.params.diagnosis,
    runout=snakemake.params.runout,
    dem=snakemake.params.dem,
    cost=snakemake.params.cost,
    name=snakemake.wildcards.name,
)
logging.info("%s: %s, validated MSE %.4g", snakemake.wildcards.name, result["route"], result["mse"])
