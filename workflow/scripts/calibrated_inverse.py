"""GNS inverse design over every parameter of a column's calibrated model: inverse.json and figures."""

import logging

from pipeline.calibrated_inverse import run_model_inverse

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
i, o = snakemake.input, snakemake.output
result = run_model_inverse(
    i.model,
    i.gns,
    i.metadata,
    i.start,
    i.measured,
    o.result,
    o.paths,
    o.deposits,
    snakemake.params.settings,
    snakemake.params.channel_width,
    runout=snakemake.params.runout,
    evaluation_path=i.evaluation,
    threads=snakemake.threads,
    packing_paths=i.packings,
    section=snakemake.params.calibration,
    dataset_paths=i.dataset,
    out_sensitivity=o.sensitivity,
)
logging.info("optimum %s, GNS objective %.4f", result.best_params, result.best_value)
