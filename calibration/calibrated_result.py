"""What the calibrated-model stage answers for one measured column (`CalibratedResult`, built by
pipeline/calibrated.py's `run_calibrated`): results/calibrated/<name>/calibrated.json.

`to_json` writes the file, `from_json` reads it back and refuses a file whose keys are not the
record's (a key missing, or one this code does not know), naming the file and the key. The routes'
records inside it (calibration.calibrated.Validation as dicts, with the runoff's entries) stay
JSON objects: the report and the frozen answer read them as such.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from calibration.calibrated import CalibrationError
from dem.atomic import StrPath, write_json


@dataclass
class CalibratedResult:
    """The answer for one measured column: which model, its parameters by each route, every route
    validated by DEM runs on the same packings, the answer, how far it transfers and what it predicts.

    MSEs are of the runout L* = (L - L_i)/L_i against the measurement (dimensionless, L*^2); times
    in seconds; parameters in their own units (friction mu and restitution e dimensionless, a
    mechanism's as calibration/mechanisms.py states it).

    name: the measured entry (the config's `measured` key); measured: its CSV's path as configured;
    column: the column's name in that file.
    model: the calibrated model, "base" or a mechanism's name; parameters [p]: its parameter names
    in the model's order; bounds [p][2]: (low, high) of each, the box every route searched; why:
    why this model (the config, or the diagnosis' answer), in words. plausible: the physically
    plausible range of the mechanism's parameter for the column's material, {parameter, range [low,
    high], source} (model.json's, calibration.mechanisms.plausible_for); None for the base model.
    answer: the route label (a `route` of routes) of the answer.
    routes: every validated route, run_validation's record (Validation.to_dict() with `key`,
    `model`, where given `own_dem_runs`, and `versus_answer`: {mse_difference, se}, its MSE minus
    the answer's paired packing by packing, with its jackknife SE, None under 3 packings).
    runoff: the routes not told apart from the best, scored on answer_packings packings
    (calibration.answer_choice.runoff's entries); [] when none ran. answer_packings: the packings the
    answer was chosen on (validation_packings without a runoff).
    intervals: 95% intervals of the parameters, the diagnosis' Laplace posterior ([{name, value,
    std, low, high, identifiable, why}]; None without a diagnosis). gns_intervals: the GNS inverse
    design's posterior intervals of the model's GNS route, gns_sensitivity: whether that GNS
    responds to each parameter (calibration.sensitivity; None where not checked); both None
    without that route. gns_vs_doe: the GNS route against each DoE route of the model, [{doe_key,
    doe_route, mse_difference (GNS minus DoE), se, packings, gns_dem_runs, gns_own_dem_runs,
    doe_dem_runs}]; [] without a GNS route.
    target: the answer carried to calibration.target_size_scale (calibration.target_scale.
    TargetCalibration.to_dict(): the coarse slopes, the correction at the target, its validation,
    the DEM runs and seconds at each scale); None where the target is the calibration's scale.
    transfer: the answer (at the target where there is one) validated at calibration.finer_size_scale
    (Validation.to_dict() and its size_scale; None when that is off). prediction: the model at the
    answer on other aspect ratios (calibration.prediction.Prediction.to_dict()), run at
    prediction_size_scale (the target's).
    measured_final_runout: the measured L* at its last t/t*; prediction_measured_a: the measured
    column's aspect ratio H_i / L_i.
    size_scale: coarse-graining factor of every DEM run; engine: the DEM engine; runout: the
    runout method the runs were read by (dem.runout.RunoutMethod.to_config()); runout_stated:
    whether the measured file states it (False: the config's).
    validation_packings: packings of every route's validation; calibration_packing: the packing
    seed the BO route calibrates on; seconds: wall time of the stage's job.
    """

    name: str
    measured: str
    column: str
    model: str
    parameters: list[str]
    bounds: list[list[float]]
    why: str
    plausible: dict[str, Any] | None
    answer: str
    routes: list[dict[str, Any]]
    runoff: list[dict[str, Any]]
    answer_packings: int
    intervals: list[dict[str, Any]] | None
    gns_intervals: list[dict[str, Any]] | None
    gns_sensitivity: list[dict[str, Any]] | None
    gns_vs_doe: list[dict[str, Any]]
    target: dict[str, Any] | None
    transfer: dict[str, Any] | None
    prediction: dict[str, Any]
    prediction_size_scale: float
    measured_final_runout: float
    prediction_measured_a: float
    size_scale: float
    engine: str
    runout: dict[str, Any]
    runout_stated: bool
    validation_packings: int
    calibration_packing: int
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of calibrated.json: one key per field, in field order, values as held."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: StrPath = "a calibrated record") -> CalibratedResult:
        """Inverse of `to_dict`; CalibrationError naming `source` and the key when a key is missing
        or unknown."""
        if not isinstance(data, dict):
            raise CalibrationError(f"{source}: not a calibrated record (a JSON object), but {type(data).__name__}")
        names = [f.name for f in fields(cls)]
        missing = [k for k in names if k not in data]
        if missing:
            raise CalibrationError(f"{source}: no key {missing[0]!r} (missing: {missing}): not a calibrated.json")
        unknown = [k for k in data if k not in names]
        if unknown:
            raise CalibrationError(f"{source}: unknown key {unknown[0]!r} (unknown: {unknown}) in a calibrated.json")
        return cls(**data)

    def to_json(self, path: StrPath) -> None:
        """Write calibrated.json at `path` (indented JSON, atomically: dem.atomic.write_json)."""
        write_json(path, self.to_dict())

    @classmethod
    def from_json(cls, path: StrPath) -> CalibratedResult:
        """The record of the calibrated.json at `path`, as `to_json` wrote it."""
        try:
            data = json.loads(Path(path).read_text())
        except ValueError as exc:
            raise CalibrationError(f"{path}: not JSON ({exc})") from exc
        return cls.from_dict(data, path)
