"""The diagnosis stage (workflow/rules/diagnosis.smk): what its design-run and diagnosis jobs do.

  - `run_library` (rule diagnosis_library): DEM design runs of the base model and of every
    candidate extension for one measured data set -> results/diagnosis/<name>/library.npz;
  - `run_diagnosis` (rule diagnosis): the diagnosis of that data set with those runs ->
    diagnosis.json, residuals.png, candidates.png in results/diagnosis/<name>/.

Its report section (rule diagnosis_section): pipeline/diagnosis_section.py. The method is
calibration/diagnosis.py (`diagnose`, `DiagnosisSettings`), its result a `Diagnosis`
(calibration/diagnosis_result.py); the figures are calibration/diagnosis_report.py's.
"""

from __future__ import annotations

import json
import logging
import warnings
from dataclasses import replace
from pathlib import Path

from calibration.design_runs import Library
from calibration.diagnosis import LIBRARY_SETTINGS, DiagnosisSettings, diagnose
from calibration.diagnosis_result import Diagnosis
from calibration.measured import MeasuredDataWarning, read_measured
from calibration.measured_column import MeasuredColumn
from calibration.observables import Observables
from dem.atomic import StrPath, write_json
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
