"""The calibrated model of one measured column: calibrated.json, calibrated.png, prediction.png and scales.png."""

import logging

from pipeline.calibrated import run_calibrated
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
result = run_calibrated(
    job,
    snakemake.input.validations,
    snakemake.input.diagnosis or None,
    snakemake.output.result,
    snakemake.output.figure,
    snakemake.output.prediction,
    snakemake.params.settings,
    snakemake.output.scales,
)
logging.info("%s: %s model, answer %s", result.name, result.model, result.answer)
