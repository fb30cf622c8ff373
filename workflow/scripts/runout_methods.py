"""Every runout method on the DAG's own DEM runs: methods.json, figure, report section."""

import logging

from pipeline.runout import run_runout_methods

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
p, i, o = snakemake.params, snakemake.input, snakemake.output
study = run_runout_methods(p.labels, i.trajectories, p.rollouts, o.study, o.figure, o.section, p.runout)
logging.info("means: %s", study["mean"])
