"""Train (or resume training) the GNS of one dataset; outputs in results/gns/<dataset>/train/."""

import logging
from pathlib import Path

from pipeline.gns import train

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
result = train(
    snakemake.input.metadata,
    Path(snakemake.output.model).parent,
    snakemake.params.settings,
    snakemake.params.runout,
    snakemake.threads,
)
logging.info("done: %s", result)
