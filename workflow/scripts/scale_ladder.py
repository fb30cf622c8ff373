"""The scale ladder: its runs read by the configured runout method; summary.json, figure, report section."""

import logging

from pipeline.scale_ladder import run_scale_ladder

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
i, o = snakemake.input, snakemake.output
summary = run_scale_ladder(i.trajectories, i.packings, o.summary, o.figure, o.section, snakemake.params.runout)
logging.info("final L* per size_scale: %s", {k: v["final_runout"]["mean"] for k, v in summary["by_size_scale"].items()})
