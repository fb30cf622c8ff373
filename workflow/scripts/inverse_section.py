"""The inverse-design report section (results/report/inverse.md)."""
import logging

from pipeline.inverse import write_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
i = snakemake.input  # noqa: F821
write_section(snakemake.params.names, i.measured, i.results, i.tables, snakemake.output[0],  # noqa: F821
              i.recovery, i.recovery_figures, bayesopt=snakemake.params.bayesopt)  # noqa: F821
logging.info("wrote %s", snakemake.output[0])  # noqa: F821
