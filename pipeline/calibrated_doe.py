"""The DoE route of the calibrated model (workflow rule calibrated_doe): for one measured column,
the face-centred central composite design over the calibrated model's parameters, one DEM run per
point, the quadratic response surface and its optimum (doe/model_study.py); given its outputs (the
rule always gives them), also the 3-level full factorial from the same runs and the grid points the
CCD lacks (k = 3: 30 runs, the GNS route's cost) -> results/calibrated/<name>/doe.json,
doe_responses.csv, doe_surface.png and doe_full_factorial.json, doe_full_factorial_surface.png (names
are the rule's).
"""

from __future__ import annotations

import logging
import time

from calibration.design_runs import SimulationSettings
from calibration.model import Model
from dem.atomic import StrPath, write_json
from dem.progress import progress_logger
from dem.run_store import keeps_runs
from dem.runout import RunoutMethod
from doe.model_study import CCD, FULL_FACTORIAL, SURFACE, design_runs, model_doe
from doe.plots import plot_surface_pairs
from doe.study import write_responses
from pipeline.calibrated_column import CalibratedColumn

log = logging.getLogger(__name__)


@keeps_runs("out_json")
def run_model_doe(
    job: CalibratedColumn,
    out_json: StrPath,
    out_responses: StrPath,
    out_figure: StrPath,
    section: dict,
    out_full_factorial: tuple[StrPath, StrPath] | None = None,
) -> dict:
    """DoE calibration of the calibrated model of one measured column (workflow rule calibrated_doe).

    section: the config's `calibration` section (doe_centre_replicates, default 3; seed: the packing
    of the non-replicate runs is CALIBRATION_SEED + seed, the BO's). Writes the
    CCD's result JSON (route, parameters, optimum in natural units, dem_runs, seconds: its runs'
    wall time and its fit's, and the DoE summary), the responses table of every run (ccd: the run
    is the CCD's) and the CCD's figure; out_full_factorial (result JSON, figure): the 3-level full
    factorial's too, from the same runs and its own. Returns the CCD's result.
    """
    started = time.perf_counter()
    column, model, why, name = job.column, job.model, job.why, job.name
    settings, runout, dem = job.settings, job.runout, job.dem
    designs = f"{CCD}{f' and {FULL_FACTORIAL}' if out_full_factorial else ''}"
    log.info("%s: DoE (%s) of the %s model %s", name, designs, model.name, list(model.parameter_names))
    responses, studies = model_doe(
        model,
        column,
        settings,
        runout,
        dem,
        centre_replicates=section.get("doe_centre_replicates", 3),
        seed=section.get("seed", 0),
        progress=progress_logger(f"DoE of {model.name} on DEM runs of {name}", log),
        full_factorial=out_full_factorial is not None,
    )
    write_responses(out_responses, responses)
    outputs = {CCD: (out_json, out_figure), **({FULL_FACTORIAL: out_full_factorial} if out_full_factorial else {})}
    results = {}
    for design, (path, figure) in outputs.items():
        summary, fit = studies[design]
        results[design] = design_result(
            name, job.measured_path, column.name, model, why, settings, runout, dem, summary
        )
        write_json(path, results[design])
        title = f"{name}: {model.name} model, DoE ({design})"
        plot_surface_pairs(fit, design_runs(responses, design), figure, title=title)
        log.info("%s: DoE (%s) optimum %s (%s)", name, design, results[design]["optimum"], summary["failures"])
    log.info("%s: DoE stage done in %.0f s", name, time.perf_counter() - started)
    return results[CCD]


def design_result(
    name: str,
    measured_path: StrPath,
    column_name: str,
    model: Model,
    why: str,
    settings: SimulationSettings,
    runout: RunoutMethod,
    dem: dict | None,
    summary: dict,
) -> dict:
    """The result JSON of one design (model_doe's summary of it): what the calibrated stage reads."""
    optimum = summary["models"][SURFACE]["optimum"]["natural"]
    return {
        "name": name,
        "measured": str(measured_path),
        "column": column_name,
        "route": f"{model.name}, DoE ({summary['design']}, {SURFACE})",
        "why": why,
        "parameters": list(model.parameter_names),
        "bounds": model.bounds.tolist(),
        "optimum": {parameter: optimum[parameter] for parameter in model.parameter_names},
        "dem_runs": summary["n_runs"],
        "size_scale": settings.size_scale,
        "engine": (dem or {}).get("engine", "builtin"),
        "runout": runout.to_config(),
        **summary,
        # the design's own cost: its runs (a CCD within the full factorial does not pay for the rest)
        "seconds": summary["dem_seconds"] + summary["analysis_time_s"],
    }
