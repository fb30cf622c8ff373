"""A campaign's answer from its routes: results/campaign/<name>/campaign.json and campaign.png."""

import logging

from pipeline.campaign import run_campaign

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
result = run_campaign(
    snakemake.input.routes,
    snakemake.input.measured,
    snakemake.wildcards.name,
    snakemake.output.result,
    snakemake.output.figure,
)
logging.info("%s: the answer is %s", result.name, result.answer)
