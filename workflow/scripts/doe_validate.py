"""DEM validation run at one model's DoE optimum (trajectory HDF5, atomically)."""
import json
import logging
from pathlib import Path

from calibration.measured import load_column
from calibration.objective import objective
from dem.engines import simulate_case
from dem.progress import progress_logger
from dem.runout import RunoutMethod
from dem.trajectory import write_trajectory
from doe.study import validation_case

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
summary = json.loads(Path(snakemake.input.analysis).read_text())  # noqa: F821
measured = load_column(snakemake.input.measured)  # noqa: F821
case = validation_case(summary, snakemake.wildcards.doe_model, measured, **snakemake.params.case_fields)  # noqa: F821
logging.info("validation %s: mu %.4f, e %.4f, %d grains", case.name, case.friction, case.restitution, case.n_particles)
trajectory = simulate_case(case, snakemake.params.dem,  # noqa: F821
                           progress=progress_logger(f"collapse {case.name}", logging.getLogger()))
write_trajectory(snakemake.output[0], trajectory)  # noqa: F821
logging.info("MSE against %s: %.4f", measured.name, objective(trajectory, measured, RunoutMethod.from_config(snakemake.params.runout)))  # noqa: F821
