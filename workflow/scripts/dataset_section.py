"""The report section on the DEM datasets (results/report/dataset.md)."""
import logging

from dem.atomic import write_text
from dem.dataset import dataset_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
text = dataset_section(snakemake.input.metadata, snakemake.input.figures, snakemake.output[0])  # noqa: F821
write_text(snakemake.output[0], text)  # noqa: F821
logging.info("wrote %s", snakemake.output[0])  # noqa: F821
