"""Build one dataset's metadata JSON (splits, normalisation statistics) from its trajectories."""
import logging

from dem.dataset import build_dataset

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
splits = {k: list(v) for k, v in snakemake.params.splits.items()}  # noqa: F821
name = snakemake.wildcards.dataset  # noqa: F821
logging.info("dataset %s: %s cases", name, {k: len(v) for k, v in splits.items()})
metadata = build_dataset(splits, snakemake.output[0], name)  # noqa: F821
logging.info("dt_frame %.4g s, %d-%d grains, velocity std %s m/frame, acceleration std %s m/frame^2",
             metadata["dt_frame"], metadata["n_particles"]["min"], metadata["n_particles"]["max"],
             metadata["velocity_std"], metadata["acceleration_std"])
