"""The diagnosis' contenders predicted across aspect ratios before the model is chosen (workflow rule
calibrated_contenders): contenders.json and its figure (its table in the report:
pipeline/contenders_section.py)."""

from __future__ import annotations

import logging

import numpy as np

from calibration.contenders import ContenderChoice, check_contenders
from calibration.design_runs import SimulationSettings
from calibration.measured import load_column
from calibration.prediction import PREDICTION_TSTAR
from calibration.scaling_laws import DISC_2D_SOURCE, QUASI_2D_SOURCE, disc_2d_runout, quasi_2d_runout
from dem.atomic import StrPath
from dem.plots import save_figure
from dem.progress import progress_logger
from dem.run_store import keeps_runs
from pipeline.diagnosis import read_diagnosis

log = logging.getLogger(__name__)


@keeps_runs("out_json")
def run_contenders(
    measured_path: StrPath,
    diagnosis_path: StrPath,
    out_json: StrPath,
    out_figure: StrPath,
    section: dict,
    diagnosis_section: dict,
    runout: dict | None,
    dem: dict | None,
    name: str = "",
) -> ContenderChoice:
    """Every model the diagnosis scored in the DEM, at its fit, and the pairs of
    section["contender_pairs"] at their DEM fits (calibration.pairs), predicted at
    section["predict_aspect_ratios"] on section["scaling_packings"] packings and held against the
    quasi-2D law with tolerance section["scaling_log_std"], each candidate's curve run at the target
    grain size too (transfer_size_scale: how far it moves), each mechanism's parameter against its
    range in section["plausible_ranges"] for the column's material (calibration.contenders) -> contenders.json
    and its figure. The grains and the runout reading are the diagnosis' (CalibratedColumn's); its
    finished DEM runs are kept, so a killed job loses only the run in flight."""
    column = load_column(measured_path)
    diagnosis = read_diagnosis(diagnosis_path)
    choice = check_contenders(
        diagnosis,
        column,
        SimulationSettings(size_scale=diagnosis_section["size_scale"]),
        section["predict_aspect_ratios"],
        column.runout_reading(runout),
        dem,
        channel_width=diagnosis_section["channel_width"],
        n_packings=section["scaling_packings"],
        law_log_std=section["scaling_log_std"],
        name=name,
        progress=progress_logger(f"{name}: the diagnosis' contenders predicted across a", log),
        plausible_ranges=section.get("plausible_ranges"),
        pairs=section.get("contender_pairs", "auto"),
        pair_packings=section.get("pair_packings", 4),
        pair_rounds=section.get("pair_rounds", 3),
        finer_size_scale=transfer_size_scale(section, diagnosis_section["size_scale"]),
    )
    choice.to_json(out_json)
    plot_contenders(choice, column.aspect_ratio, float(column.runout[-1]), out_figure)
    log.info("%s: %s", name, choice.why)
    return choice


def transfer_size_scale(section: dict, size_scale: float) -> float | None:
    """The grain size the contenders' curves are run at to weigh how far they transfer: the target's
    (calibration.target_size_scale), else the held-out finer one (finer_size_scale), where finer
    than the diagnosis' size_scale; None: neither is."""
    for key in ("target_size_scale", "finer_size_scale"):
        finer = section.get(key)
        if finer is not None and finer < size_scale:
            return float(finer)
    return None


def plot_contenders(choice: ContenderChoice, measured_a: float, measured_runout: float, path: StrPath) -> None:
    """Each contender's final runout L* against a (mean over packings, each packing a dot), the
    quasi-2D law and the true-2D disc law, the measured column on it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    a = np.array(choice.contenders[0].scaling.aspect_ratios)
    fine = np.linspace(max(a.min(), 0.1), a.max(), 100)
    ax.plot(fine, [quasi_2d_runout(x) for x in fine], "k:", lw=1.2, label=f"{QUASI_2D_SOURCE} (dry sand)")
    ax.plot(fine, [disc_2d_runout(x) for x in fine], ":", color="tab:gray", lw=1, label=DISC_2D_SOURCE)
    for k, c in enumerate(choice.contenders):
        colour = f"C{k}"
        mean = [np.nan if v is None else v for v in c.scaling.final_runout]
        chosen = " <- chosen" if c.model == choice.chosen else ""
        moved = f", move chi^2 {c.transfer_chi2:.0f}" if c.grain_shift is not None else ""
        label = f"{c.model} (BIC {c.bic:.0f}, law chi^2 {c.law_chi2:.0f}{moved}){chosen}"
        ax.plot(a, mean, "o-" if c.model != "base" else "s--", color=colour, label=label)
        for each in c.runout_each:
            ax.plot(a, [np.nan if v is None else v for v in each], ".", color=colour, alpha=0.5)
    ax.plot([measured_a], [measured_runout], "k*", ms=11, label="measured")
    ax.set(xlabel="aspect ratio a = H_i / L_i", ylabel=f"final runout L* (t/t* = {PREDICTION_TSTAR:g})")
    ax.set_title(f"{choice.name}: the diagnosis' contenders at their fits, packings {len(choice.seeds)}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
