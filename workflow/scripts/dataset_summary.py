"""One dataset's summary figure (cases by split, runout curves) and its case table as CSV."""

import logging

from pipeline.dataset import summarise

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
o = snakemake.output
summarise(snakemake.input[0], o.figure, o.cases, snakemake.params.rows, snakemake.params.runout)
logging.info("wrote %s and %s", o.figure, o.cases)
