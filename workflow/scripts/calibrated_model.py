"""Which model a measured column is calibrated as (the config's, or auto: the diagnosis' answer): model.json."""

import logging

from pipeline.calibrated import choose_model

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
record = choose_model(
    snakemake.input.diagnosis or None,
    snakemake.output[0],
    snakemake.params.model,
    snakemake.params.channel_width,
    name=snakemake.wildcards.name,
    box=snakemake.params.box,
    contenders_path=snakemake.input.contenders or None,
    measured_path=snakemake.input.measured,
    plausible_ranges=snakemake.params.plausible_ranges,
)
logging.info("%s: %s (%s)", record["name"], record["model"], record["why"])
