"""Train (or resume training) the GNS of one dataset; outputs in results/gns/<dataset>/train/."""
import logging
from pathlib import Path

from pipeline.gns import train

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
result = train(snakemake.input.metadata, Path(snakemake.output.model).parent, snakemake.params.settings,  # noqa: F821
               snakemake.params.runout, snakemake.threads)  # noqa: F821
logging.info("done: %s", result)
