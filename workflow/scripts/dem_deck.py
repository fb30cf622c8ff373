"""Write one case's deck (engine-neutral JSON) from its case-table row (params.row)."""
import logging

from dem.grid import write_deck

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
row = dict(snakemake.params.row)  # noqa: F821
case = write_deck(row, snakemake.output[0])  # noqa: F821
logging.info("deck %s: %d grains, dt %.3g s, %d frames every %.3g s", case.name, case.n_particles,
             case.time_step, case.n_frames, case.frame_interval)
