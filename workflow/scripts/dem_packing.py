"""Pour and settle one case's column behind the gate (builtin engine); a one-frame trajectory."""

import logging

from pipeline.dem import settle

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
settle(snakemake.input.deck, snakemake.output[0], snakemake.threads)
logging.info("wrote %s", snakemake.output[0])
