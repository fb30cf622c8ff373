"""Snapshots and runout curve of one case's collapse."""
import logging

from dem.plots import plot_case
from dem.trajectory import read_trajectory

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
trajectory = read_trajectory(snakemake.input[0])  # noqa: F821
plot_case(trajectory, snakemake.output[0], snakemake.params.runout)  # noqa: F821
logging.info("figure %s", snakemake.output[0])  # noqa: F821
