"""What every job of the calibrated-model stage starts from: one measured column, the model fitted
to it, and how that model is simulated and its runs read (`CalibratedColumn`).

The jobs (pipeline/calibrated.py, pipeline/calibrated_doe.py) differ in what they compute, not in
this: the column read from its CSV, the model from model.json (the workflow rule calibrated_model),
the grains coarse-grained as the diagnosis that chose the model fitted them (a fitted cohesion or
side-wall friction is an effective value of that grain size), the runout read as the file states,
else as the config says.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from calibration.calibrated import read_model
from calibration.design_runs import SimulationSettings
from calibration.measured import load_column
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from dem.atomic import StrPath
from dem.runout import RunoutMethod

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CalibratedColumn:
    """One measured column and the model the calibrated stage fits to it."""

    name: str  # the config's name of the measured entry
    measured_path: StrPath  # its CSV, as the config gives it
    column: MeasuredColumn
    model: Model  # the model of model.json, its mechanism's range the calibration box
    why: str  # why that model (model.json's words)
    settings: SimulationSettings  # the diagnosis' size_scale
    runout: RunoutMethod  # the file's stated runout reading, else the config's
    dem: dict | None  # the config's dem section (engine, threads), None: the builtin's defaults

    @classmethod
    def read(
        cls,
        measured_path: StrPath,
        model_path: StrPath,
        diagnosis_section: dict,
        *,
        runout: dict | None,
        dem: dict | None,
        name: str = "",
    ) -> CalibratedColumn:
        """From the column's CSV, its model.json, the config's `diagnosis` section (size_scale,
        channel_width) and its `runout` and `dem` sections. Logs what the file left unsaid about
        its runout reading."""
        column = load_column(measured_path)
        model, why = read_model(model_path, diagnosis_section["channel_width"])
        for note in column.runout_defaults(runout):
            log.info("%s: %s", name, note)
        return cls(
            name=name,
            measured_path=measured_path,
            column=column,
            model=model,
            why=why,
            settings=SimulationSettings(size_scale=diagnosis_section["size_scale"]),
            runout=column.runout_reading(runout),
            dem=dem,
        )
