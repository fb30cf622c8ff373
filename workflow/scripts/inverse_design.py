"""GNS inverse design of one measured column: inverse.json, paths and deposits figures."""

import logging

from pipeline.inverse_design import run_inverse_design

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
i, o = snakemake.input, snakemake.output
result = run_inverse_design(
    i.model,
    i.metadata,
    i.start,
    i.measured,
    o.result,
    o.paths,
    o.deposits,
    snakemake.params.settings,
    runout=snakemake.params.runout,
    evaluation_path=i.evaluation,
    doe_responses_path=i.doe_responses[0] if i.doe_responses else None,
    threads=snakemake.threads,
)
logging.info(
    "optimum %s, GNS objective %.4f, online %.1f s", result.best_params, result.best_value, result.seconds["online"]
)
