"""The report's first section (results/report/calibrated.md) and the answer page of every measured
column (results/report/answer_<name>.html) from every calibrated.json."""

import logging

from pipeline.answer import run_answers
from pipeline.calibrated_section import run_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
run_section(snakemake.input.results, snakemake.input.figures, snakemake.output.section)
run_answers(snakemake.input.results, snakemake.input.figures, snakemake.output.answers)
logging.info("wrote %s and %d answer pages", snakemake.output.section, len(snakemake.output.answers))
