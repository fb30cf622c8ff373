"""The DoE routes of the calibrated model of one measured column (the face-centred CCD and the 3-level
full factorial from one DEM campaign): their result JSONs, the responses and the figures."""

import logging

from pipeline.calibrated_column import CalibratedColumn
from pipeline.calibrated_doe import run_model_doe

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
job = CalibratedColumn.read(
    snakemake.input.measured,
    snakemake.input.model,
    snakemake.params.diagnosis,
    runout=snakemake.params.runout,
    dem=snakemake.params.dem,
    name=snakemake.wildcards.name,
)
result = run_model_doe(
    job,
    snakemake.output.result,
    snakemake.output.responses,
    snakemake.output.figure,
    snakemake.params.settings,
    out_full_factorial=(snakemake.output.full_factorial, snakemake.output.full_factorial_figure),
)
logging.info("%s: %s, optimum %s", result["name"], result["route"], result["optimum"])
