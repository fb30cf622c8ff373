"""Run one case's collapse from its settled packing with the configured engine; trajectory HDF5."""
import logging
import shutil

from dem.engines import get_engine
from dem.grid import read_deck
from dem.progress import progress_logger
from dem.trajectory import read_trajectory

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
params = snakemake.params  # noqa: F821
case, _ = read_deck(snakemake.input.deck)  # noqa: F821
packing = read_trajectory(snakemake.input.packing)  # noqa: F821
engine = get_engine(params.engine, {"solvers": dict(params.solvers)})
logging.info("collapse %s with the %s engine (%s): %d grains, %d frames", case.name, engine.name,
             engine.version(), case.n_particles, case.n_frames)

shutil.rmtree(params.work_dir, ignore_errors=True)  # a killed run's leftovers
# writes the output atomically, only once the engine's output reads whole
trajectory = engine.simulate(case, packing, params.work_dir, progress=progress_logger(f"collapse {case.name}", logging.getLogger()),  # noqa: E501
                             output=snakemake.output[0])  # noqa: F821
if not params.keep_work:
    shutil.rmtree(params.work_dir)
logging.info("done: %d frames of %d grains (engine %s)", trajectory.n_frames, trajectory.n_particles,
             trajectory.attrs["engine"])
