"""Score the GNS rollouts of one dataset's test cases against the DEM; metrics and figures."""

import logging
from pathlib import Path

from pipeline.gns import evaluate

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
summary = evaluate(
    snakemake.input.dem, snakemake.input.gns, Path(snakemake.output.summary).parent, snakemake.params.runout
)
logging.info(
    "runout MSE %.4g (max %.4g), position MSE %.4g d^2, %d of %d rollouts failed",
    summary["runout_mse"],
    summary["runout_mse_max"],
    summary["position_mse_d2"],
    summary["n_failed"],
    summary["n_cases"],
)
