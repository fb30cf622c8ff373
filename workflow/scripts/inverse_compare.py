"""Comparison of the calibration routes of one measured column: table, accuracy-cost and runout figures."""

import logging
from pathlib import Path

from pipeline.inverse import run_comparison

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
i, o = snakemake.input, snakemake.output
doe = {Path(path).stem: path for path in i.doe_validation}  # results/doe/<name>/validation/<model>.h5
routes = run_comparison(
    i.measured,
    i.result,
    i.validation,
    i.start,
    o.table,
    o.figure,
    o.runout,
    snakemake.params.benchmarks,
    snakemake.params.dem_runs,
    runout=snakemake.params.runout,
    bayesopt_path=i.bayesopt[0] if i.bayesopt else None,
    bayesopt_best_path=i.bayesopt_best[0] if i.bayesopt_best else None,
    doe_validation=doe or None,
)
logging.info("wrote %s: %d rows", o.table, len(routes))
