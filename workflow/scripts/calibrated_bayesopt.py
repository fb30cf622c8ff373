"""The Bayesian-optimisation route of the calibrated model of one measured column: bayesopt.json."""

import logging

from pipeline.calibrated import run_model_bayesopt
from pipeline.calibrated_column import CalibratedColumn

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
job = CalibratedColumn.read(
    snakemake.input.measured,
    snakemake.input.model,
    snakemake.params.diagnosis,
    runout=snakemake.params.runout,
    dem=snakemake.params.dem,
    name=snakemake.wildcards.name,
)
result = run_model_bayesopt(job, snakemake.output.result, snakemake.output.figure, snakemake.params.settings)
logging.info(
    "%s: %s, optimum %s (MSE %.4g on one packing)", result["name"], result["route"], result["optimum"], result["value"]
)
