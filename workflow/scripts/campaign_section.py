"""The report's section on the campaigns: results/report/campaign.md."""

import logging

from pipeline.campaign_section import run_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
run_section(snakemake.input.results, snakemake.input.figures, snakemake.output[0])
