"""Bayesian optimisation directly on DEM runs of one measured column (the third calibration route)."""

import logging

from pipeline.inverse import run_bayesopt

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
p, o = snakemake.params, snakemake.output
data = run_bayesopt(
    snakemake.input.measured,
    snakemake.input.metadata,
    o.result,
    o.figure,
    o.best,
    p.bounds,
    runout=p.runout,
    budget=p.budget,
    seed=p.seed,
    dem=p.dem,
)
logging.info("best of %d DEM runs: %s -> %.4f", data["dem_runs"], data["best_params"], data["best_value"])
