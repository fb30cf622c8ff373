"""One dataset's summary figure (cases by split, runout curves) and its case table as CSV."""
import logging

from dem.dataset import load_dataset_metadata, plot_dataset
from dem.grid import write_case_table

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
metadata = load_dataset_metadata(snakemake.input[0])  # noqa: F821
final_runout = plot_dataset(metadata, snakemake.output.figure, snakemake.params.runout)  # noqa: F821
rows = [dict(row) for row in snakemake.params.rows]  # noqa: F821
for row in rows:  # final L* beside the parameters; same path as in dataset.smk
    path = f"results/dem/{row['dataset']}/trajectories/{row['case_id']}.h5"
    row["final_L_star"] = round(final_runout[path], 4)
write_case_table(rows, snakemake.output.cases)  # noqa: F821
logging.info("summary of %s: %d cases, final L* %.3g-%.3g", metadata["name"], len(rows),
             min(final_runout.values()), max(final_runout.values()))
