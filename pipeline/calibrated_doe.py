"""The DoE route of the calibrated model (workflow rule calibrated_doe): for one measured column,
the face-centred central composite design over the calibrated model's parameters, one DEM run per
point, the quadratic response surface and its optimum (doe/model_study.py)
-> results/calibrated/<name>/doe.json, doe_responses.csv and doe_surface.png (names are the rule's).
"""

from __future__ import annotations

import logging
import time

from calibration.calibrated import read_model
from calibration.design_runs import SimulationSettings
from calibration.measured import load_column
from dem.atomic import StrPath, write_json
from dem.progress import progress_logger
from doe.model_study import DESIGN, SURFACE, model_doe
from doe.plots import plot_surface_pairs
from doe.study import write_responses

log = logging.getLogger(__name__)


def run_model_doe(
    measured_path: StrPath,
    model_path: StrPath,
    out_json: StrPath,
    out_responses: StrPath,
    out_figure: StrPath,
    section: dict,
    diagnosis_section: dict,
    *,
    runout: dict | None,
    dem: dict | None,
    name: str = "",
) -> dict:
    """DoE calibration of the calibrated model of one measured column (workflow rule calibrated_doe).

    model_path: model.json (calibration.calibrated.model_record); section: the config's
    `calibration` section (doe_centre_replicates, default 3); diagnosis_section: the config's
    `diagnosis` section (its size_scale and channel width are the calibrated model's); runout, dem:
    the config's runout and dem sections. Writes the result JSON (route, parameters, optimum in
    natural units, dem_runs, seconds and the DoE summary), the responses table and the figure.
    """
    started = time.perf_counter()
    column = load_column(measured_path)
    model, why = read_model(model_path, diagnosis_section["channel_width"])
    settings = SimulationSettings(size_scale=diagnosis_section["size_scale"])
    runout = column.runout_reading(runout)  # the column's stated method, else the config's
    log.info("%s: DoE (%s) of the %s model %s", name, DESIGN, model.name, list(model.parameter_names))
    responses, summary, fit = model_doe(
        model,
        column,
        settings,
        runout,
        dem,
        centre_replicates=section.get("doe_centre_replicates", 3),
        progress=progress_logger(f"DoE of {model.name} on DEM runs of {name}", log),
    )
    optimum = summary["models"][SURFACE]["optimum"]["natural"]
    result = {
        "name": name,
        "measured": str(measured_path),
        "column": column.name,
        "route": f"{model.name}, DoE ({DESIGN}, {SURFACE})",
        "why": why,
        "parameters": list(model.parameter_names),
        "bounds": model.bounds.tolist(),
        "optimum": {parameter: optimum[parameter] for parameter in model.parameter_names},
        "dem_runs": summary["n_runs"],
        "size_scale": settings.size_scale,
        "engine": (dem or {}).get("engine", "builtin"),
        "runout": runout.to_config(),
        **summary,
        "seconds": time.perf_counter() - started,
    }
    write_json(out_json, result)
    write_responses(out_responses, responses)
    plot_surface_pairs(fit, responses, out_figure, title=f"{name}: {model.name} model, DoE ({DESIGN})")
    log.info("%s: DoE optimum %s (%s)", name, optimum, summary["failures"])
    return result
