"""DEM design runs of the base model and of every candidate extension for one measured data set."""

import logging

from pipeline.diagnosis import run_library

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
library = run_library(
    snakemake.input.measured, snakemake.output[0], snakemake.params.settings, runout=snakemake.params.runout
)
logging.info("library: %s", {name: len(runs.theta) for name, runs in library.runs.items()})
