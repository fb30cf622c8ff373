"""The diagnosis' contenders of one measured column predicted across aspect ratios and held against
the experimental scaling law, before its model is chosen: contenders.json and its figure."""

import logging

from pipeline.calibrated_contenders import run_contenders

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
p = snakemake.params
run_contenders(
    snakemake.input.measured,
    snakemake.input.diagnosis,
    snakemake.output.result,
    snakemake.output.figure,
    p.settings,
    p.diagnosis,
    p.runout,
    {**p.dem, "workers": snakemake.config["dem"]["workers"]},  # not a param: no rerun
    name=snakemake.wildcards.name,
)
logging.info("wrote %s", snakemake.output.result)
