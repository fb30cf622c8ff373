"""The inverse design of the calibrated model's GNS route (rule calibrated_inverse; the dataset and
its DEM cases: pipeline/calibrated_gns.py): all of the model's parameters through its GNS, with the
Laplace posterior and the check of the GNS's response against its dataset's DEM runs.
"""

from __future__ import annotations

from collections.abc import Sequence

from calibration.calibrated import read_model
from calibration.inverse_plots import plot_sensitivity
from calibration.inverse_result import InverseResult
from dem.atomic import StrPath
from gns.dataset import read_metadata
from pipeline.inverse_design import run_inverse_design


def run_model_inverse(
    model_json: StrPath,
    gns_model_path: StrPath,
    metadata_path: StrPath,
    start_path: StrPath,
    measured_path: StrPath,
    out_json: StrPath,
    out_paths: StrPath,
    out_deposits: StrPath,
    settings: dict,
    channel_width: float,
    *,
    runout: dict | None,
    evaluation_path: StrPath | None = None,
    threads: int | None = None,
    packing_paths: Sequence[StrPath] = (),
    section: dict | None = None,
    dataset_paths: Sequence[StrPath] = (),
    out_sensitivity: StrPath | None = None,
) -> InverseResult:
    """The GNS inverse design over every parameter of the model (settings: the config's `inverse`
    section). The start run is the base model's (the inverse stage's start.h5): its mechanism is
    off, and so it is at the first start (the paper's (mu, e), inverse.start); the other starts
    are a Latin hypercube over all the parameters. packing_paths: trajectories of the model's
    dataset (start_packing_cases) whose first frames start rollouts too: the objective is that of
    the mean L* over the start run's packing and theirs. section: the config's `calibration`
    section (gns_optimiser, gns_budget, gns_n_initial; None: the paper's L-BFGS-B of `settings`).
    dataset_paths: the DEM runs of the model's GNS dataset: the GNS's response to each parameter is
    checked against theirs (calibration.sensitivity), drawn to out_sensitivity."""
    model, _ = read_model(model_json, channel_width)
    start_values = {m.parameter: m.off_value(*settings["start"]) for m in model.mechanisms}
    # the mechanism's box is the model's within the range trained on (as calibration.inverse.design_bounds
    # narrows mu and e): a GNS trained on the base model's runs too has seen the off value outside it
    trained = read_metadata(metadata_path)["parameter_ranges"]
    settings = {
        **settings,
        **{
            m.parameter: [max(m.bounds[0], trained[m.parameter][0]), min(m.bounds[1], trained[m.parameter][1])]
            for m in model.mechanisms
        },
    }
    result = run_inverse_design(
        gns_model_path,
        metadata_path,
        [start_path, *packing_paths],
        measured_path,
        out_json,
        out_paths,
        out_deposits,
        settings,
        runout=runout,
        evaluation_path=evaluation_path,
        threads=threads,
        design_names=model.parameter_names,
        start_values=start_values,
        dataset_paths=dataset_paths,
        optimiser=None
        if section is None
        else {
            "optimiser": section["gns_optimiser"],
            "budget": section["gns_budget"],
            "n_initial": section["gns_n_initial"],
        },
    )
    if out_sensitivity is not None and result.sensitivity is not None:
        plot_sensitivity(result.to_dict(), out_sensitivity, title=f"does the {model.name} GNS see each parameter?")
    return result
