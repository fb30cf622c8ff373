"""The GNS report section (results/report/gns.md): test-split accuracy of every trained model."""

import logging

from pipeline.gns_section import section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
section(
    snakemake.params.datasets,
    snakemake.input.summaries,
    snakemake.input.loss_curves,
    snakemake.input.metrics,
    snakemake.output[0],
)
logging.info("wrote %s", snakemake.output[0])
