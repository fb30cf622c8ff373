"""Responses of the DoE runs (runout MSE against the measured curve), regression/ANOVA, optimum,
response-surface figure."""
import logging
from pathlib import Path

from calibration.measured import load_column
from dem.runout import RunoutMethod
from doe.design import factors_from_config, read_design
from doe.plots import plot_response_surfaces
from doe.study import collect_responses, run_analysis, write_json, write_responses

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")  # noqa: F821
doe = snakemake.params.doe  # noqa: F821
design = read_design(snakemake.input.design)  # noqa: F821
measured = load_column(snakemake.input.measured)  # noqa: F821
paths = {Path(p).stem: p for p in snakemake.input.trajectories}  # noqa: F821
runout = RunoutMethod.from_config(snakemake.params.runout)  # noqa: F821
responses = collect_responses(design, paths, measured, runout)
write_responses(snakemake.output.responses, responses)  # noqa: F821
fits, summary = run_analysis(responses, factors_from_config(doe), doe["models"])
summary["runout"] = runout.to_config()
write_json(snakemake.output.analysis, summary)  # noqa: F821
plot_response_surfaces(fits, responses, snakemake.output.surface, measured_name=measured.name)  # noqa: F821
for model, fit in summary["models"].items():
    logging.info("%s: R2 %.3f, optimum %s, predicted MSE %.3f", model, fit["r_squared"],
                 fit["optimum"]["natural"], fit["optimum"]["predicted"])
