"""What a discrepancy diagnosis finds (`Diagnosis`, returned by calibration/diagnosis.py's `diagnose`).

`Diagnosis.to_dict()` is the JSON the pipeline writes (results/diagnosis/<name>/diagnosis.json),
`Diagnosis.from_dict` reads it back (the report section does). Groups of the JSON are small frozen
dataclasses here: the simulator, the columns, the observables and their noise, the evidence per
model (its emulator fit, calibration/scoring.py; its DEM score, calibration/dem_scoring.py), the
errors before and after. Chi^2 values are against the noise std (dimensionless); MSEs are of the
runout L* (L*^2); times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.decision import DecisionRule
from calibration.dem_scoring import DEMScore
from calibration.residuals import ResidualStructure
from calibration.scoring import EmulatorFit, FinalFit


def _fields(instance: Any) -> dict[str, Any]:
    """{field name: value} of a dataclass instance, in field order, without converting the values."""
    return {name: getattr(instance, name) for name in instance.__dataclass_fields__}


@dataclass(frozen=True)
class SimulatorSummary:
    """What simulated the models, and how much."""

    description: str  # in words
    engine: str  # DEM engine ("builtin")
    gns_used: bool  # whether the graph-network surrogate was used (never: not trained on the extensions)
    size_scale: float  # coarse-graining factor of the grains
    design_runs: dict[str, int]  # {model: design (and replicate) runs of its emulator}
    design_dem_seconds: float  # DEM wall time of the design runs
    refinement_runs: int  # DEM scoring runs that joined the emulators, all models
    scored_in_dem: list[str]  # models scored by DEM runs (the base model first)
    packings_per_dem_score: int  # packings R of every DEM scoring run
    rounds: int  # DEM scoring rounds

    @property
    def dem_runs(self) -> int:
        """Every DEM run of the diagnosis: design runs and the scoring runs that joined the emulators."""
        return sum(self.design_runs.values()) + self.refinement_runs

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        return _fields(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimulatorSummary:
        """Inverse of `to_dict`."""
        return cls(**data)


@dataclass(frozen=True)
class ColumnSummary:
    """One measured column."""

    name: str
    material: str
    aspect_ratio: float  # a = H_i / L_i
    L_i: float  # initial column length (m)
    source: str  # where the data come from
    n_runout: int  # runout points L*(t/t*)
    n_profile: int  # deposit-profile points (0: none measured)
    # the dem.runout method its runs were read by: the file's, else the config's (None: an older diagnosis)
    runout_reading: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        return _fields(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ColumnSummary:
        """Inverse of `to_dict`."""
        return cls(**data)


@dataclass(frozen=True, eq=False)
class ObservedData:
    """The q values compared (calibration/observables.py's order) and the noise of each."""

    labels: list[tuple[str, str, float]]  # [q] (column name, "runout" | "profile", t/t* or x (m))
    measured: np.ndarray  # [q] runout L* or deposit height (m)
    noise_measurement: np.ndarray  # [q] measurement noise std (same units)
    noise_packing: np.ndarray  # [q] packing scatter std (same units)
    noise_total: np.ndarray  # [q] sqrt(measurement^2 + packing^2): the sigma of the emulator fits
    noise_source: str  # where the noise levels come from, in words

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        return {
            "labels": [list(label) for label in self.labels],
            "measured": self.measured.tolist(),
            "noise_measurement": self.noise_measurement.tolist(),
            "noise_packing": self.noise_packing.tolist(),
            "noise_total": self.noise_total.tolist(),
            "noise_source": self.noise_source,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ObservedData:
        """Inverse of `to_dict` (as read back from JSON)."""
        arrays = ("measured", "noise_measurement", "noise_packing", "noise_total")
        return cls(
            **{
                **data,
                "labels": [tuple(label) for label in data["labels"]],
                **{k: np.asarray(data[k], float) for k in arrays},
            }
        )


@dataclass(frozen=True)
class Evidence:
    """The evidence on one model: its emulator fits and, for the base model and the leading
    candidates, its DEM score. For a candidate, also how it compares with the base model."""

    model: str  # "base" or a candidate mechanism's name
    emulator: EmulatorFit  # calibrated on its emulator, at the optimum the (last) DEM round ran
    emulator_final: FinalFit  # calibrated on its emulator after the DEM runs joined it
    dem: DEMScore | None  # scored by DEM runs; None: not among the leading candidates
    scored_in: str | None = None  # candidates: "dem" or "emulator", where the comparison below comes from
    delta_bic_vs_base: float | None = None  # candidates: BIC(base) - BIC(candidate), > 0 favours the candidate
    heldout_gain: float | None = None  # candidates: 1 - held-out chi^2 / the base model's

    @property
    def score(self) -> DEMScore | EmulatorFit:
        """The DEM score where the model was run in the DEM, else its emulator fit."""
        return self.dem or self.emulator

    def to_dict(self, with_model: bool = False) -> dict[str, Any]:
        """JSON-ready; the model's name is a key only `with_model` (the "extended" entry)."""
        out = {"model": self.model} if with_model else {}
        out.update(
            emulator=self.emulator.to_dict(),
            emulator_final=self.emulator_final.to_dict(),
            dem=None if self.dem is None else self.dem.to_dict(),
        )
        if self.scored_in is not None:
            out.update(
                scored_in=self.scored_in, delta_bic_vs_base=self.delta_bic_vs_base, heldout_gain=self.heldout_gain
            )
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any], model: str | None = None) -> Evidence:
        """Inverse of `to_dict`; `model` names it where the dict does not."""
        return cls(
            model=data.get("model", model),
            emulator=EmulatorFit.from_dict(data["emulator"]),
            emulator_final=FinalFit.from_dict(data["emulator_final"]),
            dem=None if data["dem"] is None else DEMScore.from_dict(data["dem"]),
            scored_in=data.get("scored_in"),
            delta_bic_vs_base=data.get("delta_bic_vs_base"),
            heldout_gain=data.get("heldout_gain"),
        )


@dataclass(frozen=True)
class BeforeAfter:
    """One error of the base model (before) and of the compared extension (after)."""

    before: float
    after: float

    def to_dict(self) -> dict[str, float]:
        """JSON-ready."""
        return {"before": self.before, "after": self.after}


@dataclass(frozen=True)
class Errors:
    """The gain: errors of DEM runs of the base model and of the compared model at their optima."""

    compared_model: str  # the cause, else the best candidate
    fit_mse: BeforeAfter  # runout MSE (the objective, L*^2), mean over packings
    heldout_mse: BeforeAfter  # runout MSE on the held-out points, each predicted from a fit without them
    fit_chi2: BeforeAfter
    heldout_chi2: BeforeAfter
    note: str  # how these were measured, in words

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, keys in field order."""
        return {k: v.to_dict() if isinstance(v, BeforeAfter) else v for k, v in _fields(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Errors:
        """Inverse of `to_dict`."""
        return cls(**{k: BeforeAfter(**v) if isinstance(v, dict) else v for k, v in data.items()})


@dataclass(frozen=True)
class Diagnosis:
    """What the calibrated simulation of a measured data set still gets wrong, and why.

    `to_dict()` is diagnosis.json; `extended` (the cause's evidence) and `decision_rule` are written
    there too.
    """

    name: str  # the data set's name ("" when none given)
    cause: str  # the candidate mechanism named the cause, or "none"
    verdict: str  # the decision in words
    checks: dict[str, bool]  # the decision rule's checks (calibration/decision.py) and whether each passed
    decision_rule: DecisionRule
    simulator: SimulatorSummary
    settings: dict[str, Any]  # the diagnosis settings run (DiagnosisSettings.to_dict(): the config section)
    columns: list[ColumnSummary]
    observables: ObservedData
    folds: list[str]  # [folds] what each held-out fold leaves out, in words
    residuals: ResidualStructure  # of the calibrated base model's DEM runs
    base: Evidence  # the base model (friction, restitution)
    candidates: dict[str, Evidence]  # {mechanism: evidence on the base model plus it}, every candidate
    best_candidate: str  # the candidate with the lowest BIC in DEM runs
    errors: Errors  # before (base model) and after (the cause, else the best candidate)
    warnings: list[str]  # data warnings, assumed noise levels, inexact emulators
    seconds: float  # wall time of the diagnosis
    measured: str | None = None  # the measured-data file diagnosed (set by the pipeline)

    @property
    def extended(self) -> Evidence | None:
        """The evidence on the cause; None when no cause is named."""
        return None if self.cause == "none" else self.candidates[self.cause]

    def to_dict(self) -> dict[str, Any]:
        """The JSON the pipeline writes (results/diagnosis/<name>/diagnosis.json), keys in that order."""
        extended = self.extended
        out = {
            "name": self.name,
            "cause": self.cause,
            "verdict": self.verdict,
            "checks": self.checks,
            "decision_rule": self.decision_rule.to_dict(),
            "simulator": self.simulator.to_dict(),
            "settings": self.settings,
            "columns": [c.to_dict() for c in self.columns],
            "observables": self.observables.to_dict(),
            "folds": self.folds,
            "residuals": self.residuals.to_dict(),
            "base": self.base.to_dict(),
            "candidates": {n: e.to_dict() for n, e in self.candidates.items()},
            "extended": None if extended is None else extended.to_dict(with_model=True),
            "best_candidate": self.best_candidate,
            "errors": self.errors.to_dict(),
            "warnings": self.warnings,
            "seconds": self.seconds,
        }
        if self.measured is not None:
            out["measured"] = self.measured
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Diagnosis:
        """Inverse of `to_dict` (as read back from diagnosis.json); "extended" is derived, not read."""
        return cls(
            name=data["name"],
            cause=data["cause"],
            verdict=data["verdict"],
            checks=data["checks"],
            decision_rule=DecisionRule(**data["decision_rule"]),
            simulator=SimulatorSummary.from_dict(data["simulator"]),
            settings=data["settings"],
            columns=[ColumnSummary.from_dict(c) for c in data["columns"]],
            observables=ObservedData.from_dict(data["observables"]),
            folds=data["folds"],
            residuals=ResidualStructure.from_dict(data["residuals"]),
            base=Evidence.from_dict(data["base"], "base"),
            candidates={n: Evidence.from_dict(e, n) for n, e in data["candidates"].items()},
            best_candidate=data["best_candidate"],
            errors=Errors.from_dict(data["errors"]),
            warnings=data["warnings"],
            seconds=data["seconds"],
            measured=data.get("measured"),
        )
