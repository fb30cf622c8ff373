"""The DoE report section (results/report/doe.md) and the runout before/after figure per column."""
import logging
from pathlib import Path

from dem.atomic import write_text
from doe.study import report_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
names, models = snakemake.params.names, snakemake.params.models  # noqa: F821
validation = {n: {} for n in names}
for path in snakemake.input.validation:  # noqa: F821  results/doe/<name>/validation/<model>.h5
    validation[Path(path).parent.parent.name][Path(path).stem] = path
text = report_section(names, snakemake.input.measured, snakemake.input.analysis, snakemake.input.centre,  # noqa: F821
                      validation, snakemake.output.runout, snakemake.params.benchmarks,  # noqa: F821
                      snakemake.output.section, runout=snakemake.params.runout)  # noqa: F821
write_text(snakemake.output.section, text)  # noqa: F821
logging.info("wrote %s", snakemake.output.section)  # noqa: F821
