"""The discrepancy diagnosis of one measured data set: diagnosis.json, residuals.png, candidates.png."""
import logging
from pathlib import Path

from pipeline.diagnosis import run_diagnosis

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
name = snakemake.wildcards.name  # noqa: F821
result = run_diagnosis(snakemake.input.measured, snakemake.input.library,  # noqa: F821
                       Path(snakemake.output.diagnosis).parent, snakemake.params.settings,  # noqa: F821
                       runout=snakemake.params.runout, name=name)  # noqa: F821
logging.info("%s: cause %s - %s", name, result["cause"], result["verdict"])
