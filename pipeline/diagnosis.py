"""The diagnosis stage (workflow/rules/diagnosis.smk): what its three jobs do, and its report section.

  - `run_library` (rule diagnosis_library): DEM design runs of the base model and of every
    candidate extension for one measured data set -> results/diagnosis/<name>/library.npz;
  - `run_diagnosis` (rule diagnosis): the diagnosis of that data set with those runs ->
    diagnosis.json, residuals.png, candidates.png in results/diagnosis/<name>/;
  - `run_section` (rule diagnosis_section): results/report/diagnosis.md from every diagnosis.json.

The method is calibration/diagnosis.py (`diagnose`, `DiagnosisSettings`), its result a `Diagnosis`
(calibration/diagnosis_result.py); the figures are calibration/diagnosis_report.py's.
"""

from __future__ import annotations

import json
import logging
import math
import os
import warnings
from dataclasses import replace
from pathlib import Path

from calibration.design_runs import Library
from calibration.diagnosis import LIBRARY_SETTINGS, DiagnosisSettings, diagnose
from calibration.diagnosis_result import Diagnosis, Evidence
from calibration.measured import MeasuredDataWarning, read_measured
from calibration.measured_column import MeasuredColumn
from calibration.observables import Observables
from dem.atomic import StrPath, write_json, write_text
from dem.progress import progress_logger
from dem.run_store import keeps_runs

log = logging.getLogger(__name__)


# -- the jobs --------------------------------------------------------------------------------------------
@keeps_runs("library_path")
def run_library(measured_path: StrPath, library_path: StrPath, section: dict, *, runout: dict | None) -> Library:
    """Design runs for the columns of a measured-data CSV (workflow rule diagnosis_library); their
    runouts read by `runout` (the config's runout section), which the library records."""
    columns, _ = read_columns(measured_path)
    settings = DiagnosisSettings.from_config({k: v for k, v in section.items() if k in LIBRARY_SETTINGS}, runout)
    progress = progress_logger(f"design runs of {', '.join(c.name for c in columns)}", log)
    library = settings.library(Observables(columns, settings.runout), progress)
    library.save(library_path)
    return library


@keeps_runs("out_dir")
def run_diagnosis(
    measured_path: StrPath,
    library_path: StrPath,
    out_dir: StrPath,
    section: dict,
    *,
    runout: dict | None,
    name: str = "",
) -> Diagnosis:
    """Diagnose a measured-data CSV with its design runs; write diagnosis.json, residuals.png and
    candidates.png to out_dir (workflow rule diagnosis). runout: the config's runout section; a
    library read by another method is refused (LibraryError). The Diagnosis records the CSV's path
    (`measured`)."""
    from calibration.diagnosis_report import plot_candidates, plot_residuals

    columns, data_warnings = read_columns(measured_path)
    settings = DiagnosisSettings.from_config({k: v for k, v in section.items() if k != "enabled"}, runout)
    result = diagnose(
        columns,
        settings,
        Library.load(library_path),
        data_warnings=data_warnings,
        name=name,
        progress=progress_logger(f"diagnosis of {name}: fits and DEM scoring runs", log),
    )
    result = replace(result, measured=str(measured_path))
    out_dir = Path(out_dir)
    write_diagnosis(result, out_dir / "diagnosis.json")
    plot_residuals(result, out_dir / "residuals.png")
    plot_candidates(result, out_dir / "candidates.png")
    return result


def run_section(
    names: list[str], diagnosis_paths: list[StrPath], section_path: StrPath
) -> dict[str, tuple[Diagnosis, Path]]:
    """The report section (workflow rule diagnosis_section) from the diagnosis.json of each data set
    in `names` (same order as `diagnosis_paths`); the figures lie beside each JSON file. Returns
    {name: (Diagnosis, folder)}."""
    results = {name: (read_diagnosis(path), Path(path).parent) for name, path in zip(names, diagnosis_paths)}
    write_section(results, section_path)
    return results


# -- the files ---------------------------------------------------------------------------------------------
def read_columns(path: StrPath) -> tuple[list[MeasuredColumn], list[str]]:
    """Columns of a measured-data CSV and the warnings its reader raised (as strings)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MeasuredDataWarning)
        columns = list(read_measured(path).values())
    return columns, [str(w.message) for w in caught if issubclass(w.category, MeasuredDataWarning)]


def write_diagnosis(result: Diagnosis, path: StrPath) -> None:
    """diagnosis.json (`result.to_dict()`), atomically."""
    write_json(path, result.to_dict())


def read_diagnosis(path: StrPath) -> Diagnosis:
    """The Diagnosis of a diagnosis.json (`write_diagnosis`)."""
    return Diagnosis.from_dict(json.loads(Path(path).read_text()))


# -- the report section --------------------------------------------------------------------------------------
def _parameters(evidence: Evidence) -> str:
    std_of = {p.name: p.std for p in evidence.emulator.posterior.parameters}
    parts = []
    for name, value in evidence.score.parameters.items():
        std = std_of.get(name, math.nan)
        parts.append(f"{name} = {value:.3g} &plusmn; {std:.2g}")
    return ", ".join(parts)


def section_markdown(results: dict[str, tuple[Diagnosis, StrPath]], section_path: StrPath) -> str:
    """The report section for {name: (Diagnosis, folder with its figures)}."""
    lines = [
        "What the calibrated DEM still gets wrong, and whether a missing mechanism explains it. "
        "Each measured data set is fitted by the base model (friction, restitution) and by the base "
        "model plus one candidate mechanism at a time; a cause is named only when the evidence is decisive "
        "(rule below each table). Simulator: the builtin DEM, coarse-grained, through a Gaussian-process "
        "emulator of its design runs, scored by DEM runs at the optima (the GNS is not trained on the "
        "extension parameters).",
        "",
    ]
    for name, (result, folder) in results.items():
        rel = os.path.relpath(folder, os.path.dirname(section_path))
        errors = result.errors
        lines += [
            f"### {name}",
            "",
            f"**Cause: {result.cause}.** {result.verdict}",
            "",
            f"What the calibrated base model gets wrong: {result.residuals.summary}",
            "",
            f"Simulator: builtin DEM at size_scale {result.simulator.size_scale:g}; design runs "
            f"{sum(result.simulator.design_runs.values())}, refinement runs "
            f"{result.simulator.refinement_runs}; noise: {result.observables.noise_source}.",
            "",
            "| model | parameters (&plusmn; std) | chi^2 | BIC | BIC gain | held-out chi^2 | fit MSE "
            "| held-out MSE | scored in |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for evidence in [result.base] + list(result.candidates.values()):
            model, score = evidence.model, evidence.score
            where = "DEM" if evidence.dem else "emulator"
            gain = "" if model == "base" else f"{evidence.delta_bic_vs_base:+.1f}"
            fit_mse = evidence.dem.objective if evidence.dem else evidence.emulator.fit_mse
            label = f"**{model}**" if model == result.cause else model
            lines.append(
                f"| {label} | {_parameters(evidence)} | {score.chi2:.1f} | {score.bic:.1f} | {gain} | "
                f"{score.heldout_chi2:.1f} | {fit_mse:.4f} | {score.heldout_mse:.4f} | {where} |"
            )
        lines += [
            "",
            f"Gain ({errors.compared_model} vs base, DEM runs): runout MSE "
            f"{errors.fit_mse.before:.4f} &rarr; {errors.fit_mse.after:.4f} (fit), "
            f"{errors.heldout_mse.before:.4f} &rarr; {errors.heldout_mse.after:.4f} (held out).",
            "",
            "Checks: " + ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in result.checks.items()) + ".",
            "",
        ]
        if result.warnings:
            lines += ["Warnings:", ""] + [f"- {w}" for w in result.warnings] + [""]
        lines += [f"![residuals]({rel}/residuals.png)", "", f"![candidates]({rel}/candidates.png)", ""]
    return "\n".join(lines) + "\n"


def write_section(results: dict[str, tuple[Diagnosis, StrPath]], section_path: StrPath) -> None:
    """Write section_markdown(results) to `section_path`, atomically."""
    write_text(section_path, section_markdown(results, section_path))
