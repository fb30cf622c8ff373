"""The report's section of the diagnosis (workflow rule diagnosis_section): results/report/diagnosis.md
from every measured data set's diagnosis.json (pipeline/diagnosis.py writes those), with links to
the figures beside each.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from calibration.diagnosis_result import Diagnosis, Evidence
from dem.atomic import StrPath, write_text
from pipeline.diagnosis import read_diagnosis


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


def run_section(
    names: list[str], diagnosis_paths: list[StrPath], section_path: StrPath
) -> dict[str, tuple[Diagnosis, Path]]:
    """The report section (workflow rule diagnosis_section) from the diagnosis.json of each data set
    in `names` (same order as `diagnosis_paths`); the figures lie beside each JSON file. Returns
    {name: (Diagnosis, folder)}."""
    results = {name: (read_diagnosis(path), Path(path).parent) for name, path in zip(names, diagnosis_paths)}
    write_section(results, section_path)
    return results
