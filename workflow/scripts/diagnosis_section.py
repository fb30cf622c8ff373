"""The diagnosis report section (results/report/diagnosis.md) from every diagnosis.json."""
import json
import logging
from pathlib import Path

from calibration.diagnosis_report import write_section

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
results = {name: (json.loads(Path(path).read_text()), Path(path).parent)
           for name, path in zip(snakemake.params.names, snakemake.input)}  # noqa: F821
write_section(results, snakemake.output[0])  # noqa: F821
logging.info("wrote %s (%d data sets)", snakemake.output[0], len(results))  # noqa: F821
