"""Write the DoE design table of one measured column (checked against its geometry)."""
import logging

from calibration.measured import load_column
from doe.design import design_cases, design_from_config, write_design

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
doe = snakemake.params.doe  # noqa: F821
design = design_from_config(doe)
measured = load_column(snakemake.input.measured)  # noqa: F821
cases = design_cases(design, measured, size_scale=doe["size_scale"], duration_over_tstar=doe["duration_over_tstar"])
write_design(snakemake.output[0], design)  # noqa: F821
logging.info("%d runs on %s (a = %g, L_i = %g m), %d grains each", len(design), measured.name,
             measured.aspect_ratio, measured.L_i, next(iter(cases.values())).n_particles)
