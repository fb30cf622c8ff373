"""What the calibrated simulation still gets wrong: residual structure, candidate mechanisms, the cause.

`diagnose` takes measured columns and a library of DEM design runs (calibration/design_runs.py,
compared on calibration/observables.py's observables, emulated by calibration/emulator.py) and:

1. Noise: measurement noise plus packing scatter, the same for every model (calibration/residuals.py,
   which also refuses data the diagnosis cannot judge: a DiagnosisError).
2. Emulator fits (calibration/scoring.py). The base model (mu, e) and each extension (mu, e, one
   mechanism parameter, calibration/mechanisms.py) are calibrated on a GP emulator of their design
   runs: chi^2 = sum((measured - model)^2 / sigma^2) minimised over the box (Sobol sweep, then
   L-BFGS-B), on all data and without each held-out fold (one column at a time where there are
   several, else one phase of the runout at a time).
3. DEM scoring (calibration/dem_scoring.py). The emulator is cheap but not exact (its error near
   an optimum can exceed the noise). So the base model and the `dem_top` best candidates are run
   in the DEM at their optima and at their folds' optima, on `n_packings` packings; fit chi^2, AIC
   and BIC (Gaussian noise of known sigma: -2 log L = chi^2 + const) and the held-out chi^2 come
   from these runs. The held-out chi^2, of every model alike and on the emulator too, is a
   predictive check (calibration/scoring.py's `predictive_chi2`): r^T (C_noise + J Sigma J^T)^-1 r,
   the fold fit's box-bounded Laplace covariance Sigma carried to the held-out values by the
   emulator's Jacobian J, so a parameter the fold's data leave free widens its prediction. The
   runs then join the emulators (which become exact there) and, over `n_rounds`, the optima are
   refined. After those, up to `max_rounds`, one more round while the evidence is unsettled: a
   candidate beats the base model by the rule's BIC margin, yet another check fails (a candidate
   fitted a little off its optimum can fail the held-out or runner-up margin by a fraction of the
   scatter a round of refinement removes).
4. Residuals of the calibrated base model (its DEM runs), grouped by time phase, column and
   deposit region and put in words (calibration/residuals.py), and drawn
   (calibration/diagnosis_report.py).
5. Verdict (calibration/decision.py): a cause is named only on decisive evidence in DEM runs;
   otherwise "none", with the checks that failed.
6. The gain: the objective (runout MSE, calibration/objective.py) of the DEM runs before (base
   model) and after (the cause, else the best candidate), in fit and held out.

The result is a `Diagnosis` (calibration/diagnosis_result.py); its `to_dict()` is the JSON the
pipeline writes.

Simulator: the builtin DEM (dem.collapse.simulate_collapse), coarse-grained by `size_scale`. The
GNS is not used: it is not trained on the extension parameters.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from calibration.decision import DecisionRule, decide, unsettled
from calibration.dem_scoring import DEMRuns, DEMScore, dem_evaluate, dem_runs
from calibration.design_runs import DEMRunner, Library, SimulationSettings, build_library
from calibration.diagnosis_result import (
    BeforeAfter,
    ColumnSummary,
    Diagnosis,
    Errors,
    Evidence,
    ObservedData,
    SimulatorSummary,
)
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import get_mechanisms
from calibration.model import Model
from calibration.observables import Observables
from calibration.residuals import (
    DiagnosisError,
    Fold,
    NoiseModel,
    check_data,
    held_out_folds,
    noise_model,
    residual_structure,
)
from calibration.scoring import ModelScore, score_model
from dem.runout import RunoutMethod

SIMULATOR = (
    "builtin DEM (dem.collapse.simulate_collapse), coarse-grained, through a Gaussian-process "
    "emulator of its design runs; DEM runs confirm the optima. The GNS is not used: it is not "
    "trained on the extension parameters."
)


class DiagnosisWarning(UserWarning):
    """The data can be diagnosed, but something limits how far the verdict can be trusted."""


# -- settings ------------------------------------------------------------------------------------------------
@dataclass
class DiagnosisSettings:
    """Everything the diagnosis needs besides the data (config section `diagnosis`)."""

    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    candidates: tuple | None = None  # names of candidate mechanisms; None: all five
    channel_width: float = 0.01  # m, channel of the side-wall candidate
    n_base: int = 10  # Latin-hypercube DEM runs of the base model
    n_per_mechanism: int = 8  # ... of each extension
    n_packings: int = 2  # packings of every DEM scoring run
    n_rounds: int = 1  # DEM scoring rounds; each but the last refines the emulators
    max_rounds: int | None = None  # most rounds, where the evidence is unsettled (`unsettled`); None: n_rounds
    dem_top: int = 2  # candidates (best emulator BIC) scored in the DEM
    runout_noise: float | None = None  # std of L* when the file states none
    profile_noise: float | None = None  # std of the deposit height (m)
    assumed_runout_noise: float = 0.1
    assumed_profile_noise: float = 1e-3
    rule: DecisionRule = field(default_factory=DecisionRule)
    seed: int = 0
    runout: RunoutMethod = field(default_factory=RunoutMethod)  # the config's `runout` section

    @property
    def last_round(self) -> int:
        """The most DEM scoring rounds: max_rounds, or n_rounds where none is set."""
        return self.n_rounds if self.max_rounds is None else self.max_rounds

    def models(self) -> list[Model]:
        """The base model, then the base model plus each candidate mechanism."""
        return [Model()] + [Model(m) for m in get_mechanisms(self.candidates, self.channel_width)]

    @classmethod
    def from_config(cls, section: dict, runout: dict | RunoutMethod | str | None = None) -> DiagnosisSettings:
        """From the config section `diagnosis` (schema: workflow/schemas/config.schema.yaml) and the
        config's `runout` section (None: dem.runout's default)."""
        section = dict(section)
        simulation = SimulationSettings(
            size_scale=float(section.pop("size_scale", 4.0)),
            packing_seeds=tuple(section.pop("packing_seeds", (101, 102, 103))),
        )
        rule = DecisionRule(**section.pop("rule", {}))
        if section.get("candidates") is not None:
            section["candidates"] = tuple(section["candidates"])
        known = set(cls.__dataclass_fields__) - {"simulation", "rule", "runout"}
        unknown = set(section) - known
        if unknown:
            raise DiagnosisError(
                f"config key diagnosis: unknown setting(s) {sorted(unknown)}; known: "
                f"{sorted(known | {'size_scale', 'packing_seeds', 'rule'})}"
            )
        return cls(simulation=simulation, rule=rule, runout=RunoutMethod.from_config(runout), **section)

    def to_dict(self) -> dict:
        """JSON-ready: the config section as run (candidates named, simulation settings flattened)."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__ if k not in ("simulation", "rule", "runout")}
        out.update(self.simulation.to_dict(), rule=self.rule.to_dict(), runout=self.runout.to_config())
        out["candidates"] = [m.name for m in self.models()[1:]]
        return out

    def library(self, observables: Observables, progress: Callable[[float], None] | None = None) -> Library:
        """The design runs of every model for these observables; progress(fraction done) as they run."""
        return build_library(
            observables, self.models(), self.simulation, self.n_base, self.n_per_mechanism, self.seed, progress
        )

    def noise(self, observables: Observables, library: Library) -> tuple[NoiseModel, list[str]]:
        """(NoiseModel [q], notes [str]) of the measured `observables`: these settings' noise levels
        plus the packing scatter of `library`'s repeated runs (calibration/residuals.py)."""
        return noise_model(
            observables,
            library,
            self.runout_noise,
            self.profile_noise,
            self.assumed_runout_noise,
            self.assumed_profile_noise,
        )


# -- the whole diagnosis -------------------------------------------------------------------------------------
def diagnose(
    columns: Sequence[MeasuredColumn],
    settings: DiagnosisSettings,
    library: Library | None = None,
    runner: DEMRunner | None = None,
    data_warnings: Sequence[str] = (),
    name: str = "",
    progress: Callable[[float], None] | None = None,
) -> Diagnosis:
    """The diagnosis of measured `columns` (`Diagnosis.to_dict()` is its JSON).

    library: design runs for these columns (built here when None; not modified); runner: a
    DEMRunner for them (keeps settled packings between calls). data_warnings: warnings raised
    while reading the data (they forbid naming a cause). progress: callable(fraction done) after
    every fit of all models and every model's DEM runs, or None.
    """
    started = time.perf_counter()
    observables = Observables(columns, settings.runout)
    models = settings.models()
    runner, library = _checked_inputs(observables, models, settings, library, runner)
    noise, notes = settings.noise(observables, library)
    notes += check_data(observables, library, models, noise)
    notes += [f"column {c.name!r}: {d}" for c in observables.columns for d in c.runout_defaults(settings.runout)]
    folds = held_out_folds(observables)
    library = library.copy()  # runs added while refining belong to these data, not to the shared library

    def verdict(runs: dict[str, DEMRuns], final: dict[str, ModelScore], noise: NoiseModel):
        dem = {n: dem_evaluate(r, observables, folds, noise) for n, r in runs.items()}
        emulator_best = min((final[m.name] for m in models[1:]), key=lambda s: s.bic).model
        switched_on = {m.name: mechanism_on(m, dem[m.name].parameters) for m in models[1:] if m.name in dem}
        return dem, decide(dem, settings.rule, data_warnings, emulator_best, switched_on)

    def settled(runs: dict[str, DEMRuns], final: dict[str, ModelScore], noise: NoiseModel) -> bool:
        _, (cause, checks, _) = verdict(runs, final, noise)
        return not unsettled(cause, checks)

    scores, final, runs, noise, rounds = _dem_rounds(
        settings, models, observables, folds, library, runner, noise, settled, progress
    )
    dem, (cause, checks, verdict_text) = verdict(runs, final, noise)
    notes += [  # recorded in the library (failed) and in each model's DEM score (failed_runs) too
        f"design run of {f['model']} at {f['parameters']} on packing {f['packing']} failed and is left out: "
        f"{f['reason']}"
        for f in library.failed
    ] + [
        f"DEM run of {n} {'at its fit' if not f['held_out'] else 'without ' + f['held_out']} on packing "
        f"{f['packing']} failed and is left out: {f['reason']}"
        for n, r in runs.items()
        for f in r.failed
    ]
    base_dem = dem["base"]
    structure = residual_structure(observables, base_dem.observed_mean, base_dem.sigma, models[0].n_parameters)
    best = min((n for n in dem if n != "base"), key=lambda n: dem[n].bic)
    emulator_notes = [
        f"emulator of {s.model}: leave-one-out error {s.emulator_loo_over_noise:.2g} x the noise (median over outputs)"
        for s in scores.values()
        if s.emulator_loo_over_noise > 1.0
    ]
    for note in notes + emulator_notes:
        warnings.warn(f"{name or 'diagnosis'}: {note}", DiagnosisWarning, stacklevel=2)
    base = _evidence("base", scores, final, dem, observables)
    return Diagnosis(
        name=name,
        cause=cause,
        verdict=verdict_text,
        checks=checks,
        decision_rule=settings.rule,
        simulator=_simulator(settings, library, list(dem), rounds),
        settings=settings.to_dict(),
        columns=[_column(c, observables) for c in observables.columns],
        observables=ObservedData(
            observables.labels, observables.measured, noise.measurement, noise.packing, noise.total, noise.source
        ),
        folds=[f.description for f in folds],
        residuals=structure,
        base=base,
        candidates={m.name: _evidence(m.name, scores, final, dem, observables, base) for m in models[1:]},
        best_candidate=best,
        errors=_errors(dem, cause if cause != "none" else best, settings, observables, folds),
        warnings=list(data_warnings) + notes + emulator_notes,
        seconds=time.perf_counter() - started,
    )


def _checked_inputs(
    observables: Observables,
    models: list[Model],
    settings: DiagnosisSettings,
    library: Library | None,
    runner: DEMRunner | None,
) -> tuple[DEMRunner, Library]:
    """The runner and the library (each made here when None), refused (DiagnosisError) when made for
    other columns or settings; the settings refused when they cannot sample the packing scatter."""
    if runner is None:
        runner = DEMRunner(observables, settings.simulation)
    if runner.observables.signature() != observables.signature() or runner.settings != settings.simulation:
        raise DiagnosisError("the DEM runner was made for other columns or simulation settings")
    if library is None:
        library = settings.library(observables)
    library.check(observables, models)
    if float(library.settings["size_scale"]) != settings.simulation.size_scale:
        raise DiagnosisError(
            f"the run library was built at size_scale {library.settings['size_scale']}, "
            f"the diagnosis asks for {settings.simulation.size_scale}"
        )
    if settings.n_packings < 1 or settings.n_rounds < 1 or settings.dem_top < 1:
        raise DiagnosisError("n_packings, n_rounds and dem_top must be at least 1")
    if settings.last_round < settings.n_rounds:
        raise DiagnosisError(f"max_rounds = {settings.max_rounds} is below n_rounds = {settings.n_rounds}")
    if settings.n_packings > len(settings.simulation.packing_seeds):
        raise DiagnosisError(
            f"n_packings = {settings.n_packings} exceeds the {len(settings.simulation.packing_seeds)} "
            "packing seeds: repeated runs would repeat a packing, not sample the scatter"
        )
    return runner, library


def _score_all(
    models: list[Model], library: Library, observables: Observables, noise: NoiseModel, folds: list[Fold], seed: int
) -> dict[str, ModelScore]:
    """{model: its fit on its emulator of `library`'s runs} against the data's `noise`."""
    return {
        m.name: score_model(
            m, library.emulator(m, seed + k), observables, noise.total, folds, seed=seed, n_data=noise.n_effective
        )
        for k, m in enumerate(models)
    }


def _dem_rounds(
    settings: DiagnosisSettings,
    models: list[Model],
    observables: Observables,
    folds: list[Fold],
    library: Library,
    runner: DEMRunner,
    noise: NoiseModel,
    settled: Callable[[dict[str, DEMRuns], dict[str, ModelScore], NoiseModel], bool],
    progress: Callable[[float], None] | None = None,
) -> tuple[dict[str, ModelScore], dict[str, ModelScore], dict[str, DEMRuns], NoiseModel, int]:
    """The DEM scoring rounds: each runs the base model and the `dem_top` candidates (emulator BIC)
    in the DEM at their emulator optima; the runs join `library` (modified), and the models are
    fitted again. `n_rounds` rounds, then more up to `settings.last_round` until settled(the
    round's runs, the final fits, the noise model) holds. Returns (the fits the last round ran,
    the final fits, the last round's runs, the noise model with their packing scatter, the rounds
    run). progress: callable(fraction of the fits and DEM runs done, counted over the most
    rounds; 1 after the last) or None."""
    by_name = {m.name: m for m in models}
    n_dem = 1 + min(settings.dem_top, len(models) - 1)  # models run in the DEM per round
    steps, done = 1 + settings.last_round * (n_dem + 1), [0]

    def step(last: bool = False):
        done[0] += 1
        if progress is not None:
            progress(1.0 if last else done[0] / steps)

    final = _score_all(models, library, observables, noise, folds, settings.seed)
    step()
    round_ = 0
    while True:
        scores = final  # the emulator optima this round runs in the DEM (reported with its DEM scores)
        leading = sorted((scores[m.name] for m in models[1:]), key=lambda s: s.bic)[: settings.dem_top]
        runs = {}
        for n in ["base"] + [s.model for s in leading]:
            runs[n] = dem_runs(runner, by_name[n], scores[n], folds, settings.n_packings, round_ * settings.n_packings)
            step()
        # the runs join their models' emulators (exact there from now on), and their repeats on
        # different packings join the estimate of the packing scatter
        for n, r in runs.items():
            sets = [(r.theta, r.fit, r.packings)] + list(zip(r.fold_theta, r.folds, r.fold_packings))
            for theta, observed, packings in sets:  # the runs that ran (a failed one has no observables)
                for packing, one in zip(packings, observed, strict=True):
                    library.add_runs(by_name[n], theta, one, packing, r.seconds / (len(r.folds) + 1) / len(observed))
        noise, _ = settings.noise(observables, library)
        # rescored on the emulators that now hold these runs: the next round's optima, and after
        # the last round the emulators' final word, which the DEM ranking must agree with
        final = _score_all(models, library, observables, noise, folds, settings.seed)
        round_ += 1
        last = round_ >= settings.last_round or (round_ >= settings.n_rounds and settled(runs, final, noise))
        step(last)
        if last:
            return scores, final, runs, noise, round_


def _evidence(
    name: str,
    scores: dict[str, ModelScore],
    final: dict[str, ModelScore],
    dem: dict[str, DEMScore],
    observables: Observables,
    base: Evidence | None = None,
) -> Evidence:
    """The evidence on model `name`; for a candidate (`base` given), compared with the base model's
    DEM score where the candidate has one, else with its emulator fit."""
    d = dem.get(name)
    evidence = Evidence(name, scores[name].summary(observables), final[name].final(), d)
    if base is None:
        return evidence
    source = d if d is not None else evidence.emulator
    reference = base.dem if d is not None else base.emulator
    return replace(
        evidence,
        scored_in="dem" if d is not None else "emulator",
        delta_bic_vs_base=reference.bic - source.bic,
        heldout_gain=1 - source.heldout_chi2 / reference.heldout_chi2,
    )


def _simulator(
    settings: DiagnosisSettings, library: Library, scored_in_dem: list[str], rounds: int
) -> SimulatorSummary:
    """The DEM runs behind a diagnosis: design runs per model, refinement runs, DEM scoring."""
    return SimulatorSummary(
        description=SIMULATOR,
        engine="builtin",
        gns_used=False,
        size_scale=settings.simulation.size_scale,
        design_runs={n: int(np.sum(r.stage != "refine")) for n, r in library.runs.items()},
        design_dem_seconds=float(sum(r.seconds[r.stage != "refine"].sum() for r in library.runs.values())),
        refinement_runs=int(sum(np.sum(r.stage == "refine") for r in library.runs.values())),
        scored_in_dem=scored_in_dem,
        packings_per_dem_score=settings.n_packings,
        rounds=rounds,
    )


def _column(c: MeasuredColumn, observables: Observables) -> ColumnSummary:
    return ColumnSummary(
        name=c.name,
        material=c.material,
        aspect_ratio=c.aspect_ratio,
        L_i=c.L_i,
        source=c.source,
        n_runout=len(c.t_over_tstar),
        n_profile=0 if c.profile_x is None else len(c.profile_x),
        runout_reading=observables.reading(c).method,
    )


def _errors(
    dem: dict[str, DEMScore], after: str, settings: DiagnosisSettings, observables: Observables, folds: list[Fold]
) -> Errors:
    """Errors of the base model's DEM runs (before) and of model `after`'s."""
    before, other = dem["base"], dem[after]
    n_runout = int((observables.kind == "runout").sum())
    return Errors(
        compared_model=after,
        fit_mse=BeforeAfter(before.objective, other.objective),
        heldout_mse=BeforeAfter(before.heldout_mse, other.heldout_mse),
        fit_chi2=BeforeAfter(before.chi2, other.chi2),
        heldout_chi2=BeforeAfter(before.heldout_chi2, other.heldout_chi2),
        note=(
            f"DEM runs ({settings.n_packings} packings) at the calibrated parameters; MSE = the runout "
            f"objective over {n_runout} points; held out: "
            f"{'; '.join(f.description for f in folds)}, each predicted from a fit without it"
        ),
    )


# Settings that change the design runs (the library); the others only change the analysis. Read by
# workflow/rules/diagnosis.smk (the library rule's params) and pipeline/diagnosis.py.
LIBRARY_SETTINGS = ("size_scale", "packing_seeds", "candidates", "channel_width", "n_base", "n_per_mechanism", "seed")


def mechanism_on(model: Model, parameters: dict) -> bool:
    """Whether `model`'s fitted `parameters` switch its mechanism on (Mechanism.switched_on: beyond
    OFF_TOLERANCE of its range from the off value at the fitted (mu, e)); the base model's: False.
    A candidate fitted with its mechanism off is the base model at another (mu, e): its BIC gain
    over the base is the base's own fit falling short (a chaotic objective, searched from other
    runs), not evidence for the mechanism."""
    return model.mechanism is not None and model.mechanism.switched_on(parameters)
