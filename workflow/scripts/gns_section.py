"""The GNS report section (results/report/gns.md): test-split accuracy of every trained model."""
import logging

from dem.atomic import write_text
from gns.evaluate import report_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
text = report_section(snakemake.params.datasets, snakemake.input.summaries, snakemake.input.loss_curves,  # noqa: F821
                      snakemake.input.metrics, snakemake.output[0])  # noqa: F821
write_text(snakemake.output[0], text)  # noqa: F821
logging.info("wrote %s", snakemake.output[0])  # noqa: F821
