"""GNS rollout of one test case from its first C frames (engine "gns" trajectory HDF5)."""
import logging

import torch

from gns.evaluate import rollout_case

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
torch.set_num_threads(snakemake.threads)  # noqa: F821
rollout_case(snakemake.input.model, snakemake.input.dem, snakemake.output[0], snakemake.input.metadata)  # noqa: F821
