"""A DEM run of a measured column with the GNS dataset's DEM model: at the start point
(rule inverse_start) or at the GNS optimum read from inverse.json (rule inverse_validate)."""
import logging

from calibration.compare import run_dem_point
from calibration.inverse import read_result

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
if "result" in snakemake.input.keys():  # noqa: F821
    result = read_result(snakemake.input.result)  # noqa: F821
    params, name = dict(zip(result["names"], result["best_params"])), "gns_optimum"
else:
    params, name = dict(zip(("friction", "restitution"), snakemake.params.start)), "start"  # noqa: F821
summary = run_dem_point(snakemake.input.measured, snakemake.input.metadata, params, snakemake.output[0],  # noqa: F821
                        runout=snakemake.params.runout, seed=snakemake.params.seed, name=name,  # noqa: F821
                        dem=snakemake.params.dem)  # noqa: F821
logging.info("%s: %s -> objective %.4f", name, params, summary["mse"])
