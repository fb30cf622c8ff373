"""Run one case's collapse from its settled packing with the configured engine; trajectory HDF5."""

import logging

from pipeline.dem import run_case

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
p = snakemake.params
run_case(
    snakemake.input.deck,
    snakemake.input.packing,
    snakemake.output[0],
    p.engine,
    p.solvers,
    p.keep_work,
    p.work_dir,
    snakemake.threads,
)
logging.info("wrote %s", snakemake.output[0])
