"""The inverse-design report section (results/report/inverse.md)."""
import logging
from pathlib import Path

from calibration.compare import report_section
from dem.atomic import write_text

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
i, names = snakemake.input, snakemake.params.names  # noqa: F821
figures = {}
for name, result in zip(names, i.results):
    folder = Path(result).parent
    figures[name] = {key: folder / f"{key}.png" for key in ("paths", "deposits", "runout", "comparison")}
    if snakemake.params.bayesopt:  # noqa: F821
        figures[name]["bayesopt"] = folder / "bayesopt.png"
text = report_section(names, i.measured, i.results, i.tables, figures, snakemake.output[0],  # noqa: F821
                      i.recovery, i.recovery_figures)
write_text(snakemake.output[0], text)  # noqa: F821
logging.info("wrote %s", snakemake.output[0])  # noqa: F821
