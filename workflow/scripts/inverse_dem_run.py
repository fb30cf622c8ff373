"""A DEM run of a measured column with the GNS dataset's DEM model: at the start point
(rule inverse_start) or at the GNS optimum read from inverse.json (rule inverse_validate)."""

import logging

from pipeline.inverse import run_dem_at

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
i, p = snakemake.input, snakemake.params
name, params, summary = run_dem_at(
    i.measured,
    i.metadata,
    snakemake.output[0],
    runout=p.runout,
    seed=p.seed,
    dem=p.dem,
    result_path=i.result if "result" in i.keys() else None,
    start=p.start if "start" in p.keys() else None,
)
logging.info("%s: %s -> objective %.4f", name, params, summary["mse"])
