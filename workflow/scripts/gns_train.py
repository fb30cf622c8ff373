"""Train (or resume training) the GNS of one dataset; outputs in results/gns/<dataset>/train/."""
import logging
from pathlib import Path

import torch

from gns.train import TrainSettings, train

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
torch.set_num_threads(snakemake.threads)  # noqa: F821
settings = TrainSettings.from_config(snakemake.params.settings)  # noqa: F821
logging.info("settings %s", settings)
result = train(snakemake.input.metadata, Path(snakemake.output.model).parent, settings,  # noqa: F821
               restart_on_mismatch=True, runout=snakemake.params.runout)  # noqa: F821
logging.info("done: %s", result)
