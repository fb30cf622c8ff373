"""The calibrated model's answer rerun on its validation packings, each as a ParaView time series."""

import logging

from pipeline.export import export_calibrated_vtk

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
exports = export_calibrated_vtk(
    snakemake.input.calibrated,
    snakemake.input.model,
    snakemake.input.measured,
    snakemake.output[0],
    channel_width=snakemake.params.channel_width,
    dem=snakemake.params.dem,
)
logging.info("%s: %d validation runs -> %s", snakemake.wildcards.name, len(exports), snakemake.output[0])
