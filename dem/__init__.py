"""DEM side: collapse cases, the builtin engine, solver engines, trajectory HDF5, runout."""
