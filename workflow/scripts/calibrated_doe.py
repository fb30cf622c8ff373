"""The DoE route of the calibrated model of one measured column: its result JSON, responses and figure."""

import logging

from pipeline.calibrated_doe import run_model_doe

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
result = run_model_doe(
    snakemake.input.measured,
    snakemake.input.model,
    snakemake.output.result,
    snakemake.output.responses,
    snakemake.output.figure,
    snakemake.params.settings,
    snakemake.params.diagnosis,
    runout=snakemake.params.runout,
    dem=snakemake.params.dem,
    name=snakemake.wildcards.name,
)
logging.info("%s: %s, optimum %s", result["name"], result["route"], result["optimum"])
