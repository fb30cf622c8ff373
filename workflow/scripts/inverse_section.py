"""The inverse-design report section (results/report/inverse.md)."""

import logging

from pipeline.inverse_section import write_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
i = snakemake.input
write_section(
    snakemake.params.names,
    i.measured,
    i.results,
    i.tables,
    snakemake.output[0],
    i.recovery,
    i.recovery_figures,
    bayesopt=snakemake.params.bayesopt,
)
logging.info("wrote %s", snakemake.output[0])
