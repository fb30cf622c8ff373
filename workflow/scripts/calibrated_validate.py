"""One calibration route's optimum of one measured column validated on several packings."""

import logging

from pipeline.calibrated import run_validation
from pipeline.calibrated_column import CalibratedColumn

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
job = CalibratedColumn.read(
    snakemake.input.measured,
    snakemake.input.model,
    snakemake.params.diagnosis,
    runout=snakemake.params.runout,
    dem={**snakemake.params.dem, "workers": snakemake.config["dem"]["workers"]},  # not a param: no rerun
    name=snakemake.wildcards.name,
)
result = run_validation(
    job,
    snakemake.wildcards.route,
    snakemake.input.source,
    snakemake.output[0],
    snakemake.params.settings,
    cost=snakemake.params.cost,
)
logging.info("%s: %s, validated MSE %.4g", snakemake.wildcards.name, result["route"], result["mse"])
