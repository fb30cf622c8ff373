"""One trajectory HDF5 (a GNS rollout, a DEM run or validation) as a ParaView time series (.pvd + .vtu per frame)."""

import logging

from pipeline.export import export_trajectory_vtk

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
export = export_trajectory_vtk(snakemake.input[0], snakemake.output[0])
logging.info("wrote %s (%d frames)", export.pvd, len(export.frames))
