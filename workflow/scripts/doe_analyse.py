"""Responses of the DoE runs (runout MSE against the measured curve), regression/ANOVA, optimum,
response-surface figure."""

import logging

from pipeline.doe import analyse

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
analyse(
    snakemake.input.design,
    snakemake.input.measured,
    snakemake.input.trajectories,
    snakemake.params.doe,
    snakemake.params.runout,
    snakemake.output.responses,
    snakemake.output.analysis,
    snakemake.output.surface,
)
logging.info("wrote %s", snakemake.output.analysis)
