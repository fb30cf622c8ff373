"""The discrepancy diagnosis of one measured data set: diagnosis.json, residuals.png, candidates.png."""

import logging
from pathlib import Path

from pipeline.diagnosis import run_diagnosis

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
name = snakemake.wildcards.name
result = run_diagnosis(
    snakemake.input.measured,
    snakemake.input.library,
    Path(snakemake.output.diagnosis).parent,
    snakemake.params.settings,
    runout=snakemake.params.runout,
    name=name,
)
logging.info("%s: cause %s - %s", name, result.cause, result.verdict)
