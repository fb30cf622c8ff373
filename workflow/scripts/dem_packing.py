"""Pour and settle one case's column behind the gate (builtin engine); a one-frame trajectory."""
import logging

from dem.grid import read_deck
from dem.packing import settle_column
from dem.trajectory import write_trajectory

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
case, _ = read_deck(snakemake.input.deck)  # noqa: F821
logging.info("settling %s: %d grains", case.name, case.n_particles)
packing = settle_column(case, progress=lambda done: logging.info("settling: rest criterion %.0f%%", 100 * done))
write_trajectory(snakemake.output[0], packing)  # noqa: F821
logging.info("settled height %.4g m after %s steps", packing.attrs["settled_height"], packing.attrs["settle_steps"])
