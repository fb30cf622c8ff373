"""Parameter recovery of synthetic DEM targets with one dataset's GNS."""

import logging

from pipeline.inverse_design import run_recovery

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
s, i, o = snakemake.params.settings, snakemake.input, snakemake.output
summary = run_recovery(
    i.model,
    i.metadata,
    o.result,
    o.figure,
    runout=snakemake.params.runout,
    dem=snakemake.params.dem,
    threads=snakemake.threads,
    n_cases=s["recovery_cases"],
    noise_std=s["recovery_noise_std"],
    packings=s["recovery_packings"],
    evaluation_path=i.evaluation,
    seed=s["seed"],
    start=s["start"],
    bounds=[s["friction"], s["restitution"]],
    n_starts=s["starts"],
    gradient=s["gradient"],
    fd_step=s["fd_step"],
    max_iterations=s["max_iterations"],
)
logging.info(
    "mu within %g in %d of %d, truth inside 95%% in %d",
    summary["mu_tolerance"],
    summary["mu_within"],
    summary["n_cases"],
    summary["truth_inside_95"],
)
