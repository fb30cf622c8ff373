"""What the calibrated simulation still gets wrong: residual structure, candidate mechanisms, the cause.

`diagnose` takes measured columns and a library of DEM design runs (calibration/design_runs.py,
compared on calibration/observables.py's observables, emulated by calibration/emulator.py) and:

1. Noise: measurement noise plus packing scatter, the same for every model (calibration/residuals.py,
   which also refuses data the diagnosis cannot judge: a DiagnosisError).
2. Emulator fits. The base model (mu, e) and each extension (mu, e, one mechanism parameter,
   calibration/mechanisms.py) are calibrated on a GP emulator of their design runs: chi^2 =
   sum((measured - model)^2 / sigma^2) minimised over the box (Sobol sweep, then L-BFGS-B), on all
   data and without each held-out fold (one column at a time where there are several, else one
   phase of the runout at a time).
3. DEM scoring. The emulator is cheap but not exact (its error near an optimum can exceed the
   noise). So the base model and the `dem_top` best candidates are run in the DEM at their optima
   and at their folds' optima, on `n_packings` packings; fit chi^2, AIC and BIC (Gaussian noise
   of known sigma: -2 log L = chi^2 + const) and the held-out chi^2 come from these runs. The
   runs then join the emulators (which become exact there) and, over `n_rounds`, the optima are
   refined.
4. Residuals of the calibrated base model (its DEM runs), grouped by time phase, column and
   deposit region and put in words (calibration/residuals.py), and drawn
   (calibration/diagnosis_report.py).
5. Verdict (calibration/decision.py): a cause is named only on decisive evidence in DEM runs;
   otherwise "none", with the checks that failed.
6. The gain: the objective (runout MSE, calibration/objective.py) of the DEM runs before (base
   model) and after (the cause, else the best candidate), in fit and held out.

Simulator: the builtin DEM (dem.collapse.simulate_collapse), coarse-grained by `size_scale`. The
GNS is not used: it is not trained on the extension parameters.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize
from scipy.stats import chi2 as chi2_distribution
from scipy.stats import qmc
from threadpoolctl import threadpool_limits

from calibration.decision import DecisionRule, decide
from calibration.design_runs import DEMRunner, Library, Model, SimulationSettings, build_library
from calibration.emulator import GPEmulator
from calibration.mechanisms import get_mechanisms
from calibration.objective import runout_mse
from calibration.observables import Observables
from calibration.residuals import (
    DiagnosisError,
    NoiseModel,
    check_data,
    held_out_folds,
    noise_model,
    residual_structure,
)
from calibration.uncertainty import laplace_posterior
from dem.runout import RunoutMethod

log = logging.getLogger(__name__)

SIMULATOR = (
    "builtin DEM (dem.collapse.simulate_collapse), coarse-grained, through a Gaussian-process "
    "emulator of its design runs; DEM runs confirm the optima. The GNS is not used: it is not "
    "trained on the extension parameters."
)


class DiagnosisWarning(UserWarning):
    """The data can be diagnosed, but something limits how far the verdict can be trusted."""


# -- fitting on the emulator ------------------------------------------------------------------------------
def fit_emulated(emulator: GPEmulator, target, sigma, mask=None, seed: int = 0, n_sweep: int = 1024):
    """(theta [p], chi^2) minimising chi^2 over the emulator's box on the outputs in `mask` [q] bool.

    A Sobol sweep of the box's unit cube, then L-BFGS-B from the three best points: the emulator is
    cheap, and a sweep does not get stuck where a mechanism switches on.
    """
    mask = np.ones(len(target), bool) if mask is None else np.asarray(mask, bool)
    weight = 1.0 / sigma[mask]

    def chi2(unit):
        return np.sum(((emulator.predict_unit(unit)[:, mask] - target[mask]) * weight) ** 2, axis=1)

    sweep = qmc.Sobol(d=len(emulator.bounds), seed=seed).random(n_sweep)
    values = chi2(sweep)
    best_unit, best_value = sweep[int(np.argmin(values))], float(values.min())
    with threadpool_limits(1):  # tiny problems: BLAS threads only fight over the shared cores
        for start in sweep[np.argsort(values)[:3]]:
            result = minimize(lambda u: float(chi2(u)[0]), start, method="L-BFGS-B", bounds=[(0, 1)] * len(start))
            if result.fun < best_value:
                best_unit, best_value = np.clip(result.x, 0, 1), float(result.fun)
    return emulator.box.from_unit(best_unit)[0], best_value


@dataclass
class ModelScore:
    """A model calibrated on its emulator, and how well it does there."""

    model: str
    parameter_names: list
    theta: np.ndarray
    predicted: np.ndarray  # [q] emulated observables at theta
    chi2: float
    n_data: int
    n_parameters: int
    fold_theta: list  # [folds] parameters fitted without each fold
    heldout_chi2: float
    heldout_mse: float  # runout MSE (the objective) on held-out runout points
    posterior: dict
    emulator_loo_over_noise: float  # median over outputs of the emulator's LOO RMSE / total noise
    mechanism_z_off: float | None = None  # |parameter - off| / std for an extension

    @property
    def bic(self) -> float:
        return bic(self.chi2, self.n_parameters, self.n_data)

    def to_dict(self, observables: Observables) -> dict:
        runout = observables.kind == "runout"
        return {
            "parameters": dict(zip(self.parameter_names, map(float, self.theta))),
            "posterior": self.posterior,
            "chi2": self.chi2,
            "n_data": self.n_data,
            "n_parameters": self.n_parameters,
            "p_value": p_value(self.chi2, self.n_parameters, self.n_data),
            "aic": aic(self.chi2, self.n_parameters),
            "bic": self.bic,
            "fit_mse": runout_mse(self.predicted[runout], observables.measured[runout]),
            "heldout_chi2": self.heldout_chi2,
            "heldout_mse": self.heldout_mse,
            "heldout_parameters": [dict(zip(self.parameter_names, map(float, t))) for t in self.fold_theta],
            "emulator_loo_over_noise": self.emulator_loo_over_noise,
            "mechanism_z_off": self.mechanism_z_off,
        }


def aic(chi2: float, n_parameters: int) -> float:
    """Akaike information criterion under Gaussian noise of known sigma: -2 log L = chi^2 + const."""
    return chi2 + 2 * n_parameters


def bic(chi2: float, n_parameters: int, n_data: int) -> float:
    return chi2 + n_parameters * math.log(n_data)


def p_value(chi2: float, n_parameters: int, n_data: int) -> float:
    """P(chi^2 >= observed) with n - p degrees of freedom, if the model and the noise were right."""
    return float(chi2_distribution.sf(chi2, max(n_data - n_parameters, 1)))


def score_model(
    model: Model, emulator: GPEmulator, observables: Observables, sigma, folds, seed: int = 0
) -> ModelScore:
    """Calibrate `model` on its emulator on all data and without each fold; its Laplace posterior."""
    target = observables.measured
    theta, chi2 = fit_emulated(emulator, target, sigma, seed=seed)
    predicted = emulator.predict(theta)[0]
    heldout_chi2, squared, fold_theta = 0.0, [], []
    for fold in folds:
        theta_k, _ = fit_emulated(emulator, target, sigma, mask=~fold.held, seed=seed + 1, n_sweep=512)
        prediction = emulator.predict(theta_k)[0]
        heldout_chi2 += float(np.sum(((prediction[fold.held] - target[fold.held]) / sigma[fold.held]) ** 2))
        runout = fold.held & (observables.kind == "runout")
        squared += list((prediction[runout] - target[runout]) ** 2)
        fold_theta.append(theta_k)
    unit = model.box.to_unit(theta)[0]
    jacobian = []
    for j in range(model.n_parameters):  # central differences of 2% of the unit cube, kept inside it
        up, down = unit.copy(), unit.copy()
        up[j], down[j] = min(unit[j] + 0.02, 1.0), max(unit[j] - 0.02, 0.0)
        theta_up, theta_down = model.box.from_unit(up)[0], model.box.from_unit(down)[0]
        jacobian.append(
            (emulator.predict(theta_up)[0] - emulator.predict(theta_down)[0]) / (theta_up[j] - theta_down[j])
        )
    posterior = laplace_posterior(
        list(model.parameter_names),
        theta,
        np.stack(jacobian, axis=1),
        predicted - target,
        model.bounds.tolist(),
        sigma=sigma,
    )
    z_off = None
    if model.mechanism is not None:
        off = model.mechanism.off_value(theta[0], theta[1])
        std = posterior.parameters[-1].std
        z_off = float(abs(theta[-1] - off) / std) if std > 0 else math.inf
    return ModelScore(
        model.name,
        list(model.parameter_names),
        theta,
        predicted,
        float(chi2),
        observables.size,
        model.n_parameters,
        fold_theta,
        heldout_chi2,
        float(np.mean(squared)) if squared else math.nan,
        posterior.to_dict(),
        float(np.median(emulator.loo_rmse() / sigma)),
        z_off,
    )


# -- scoring in the DEM itself ---------------------------------------------------------------------------
def dem_runs(
    runner: DEMRunner, model: Model, score: ModelScore, folds, n_packings: int, first_packing: int = 0
) -> dict:
    """DEM runs of `model` at the emulator's optima: at the calibrated parameters and at each
    fold's (every column, so that the runs can also refine the emulator), on `n_packings` packings.

    Returns {"model", "theta" [p], "fit" [R, q], "fold_theta" [folds][p], "folds" [folds][R, q],
    "packings" [R], "curves" (runout curves of the fit runs), "seconds" (total)}.
    """
    n_pool = len(runner.settings.packing_seeds)
    packings = [(first_packing + r) % n_pool for r in range(n_packings)]
    started = time.perf_counter()
    fit, curves = [], []
    for k in packings:
        trajectories = runner.trajectories(model, score.theta, k)
        fit.append(runner.observables.from_trajectories(trajectories))
        curves.append([_thin_curve(tr, runner.observables.runout) for tr in trajectories])
    fold_runs = [np.array([runner.observe(model, theta_k, k) for k in packings]) for theta_k in score.fold_theta]
    return {
        "model": model,
        "theta": score.theta,
        "fit": np.array(fit),
        "fold_theta": score.fold_theta,
        "folds": fold_runs,
        "packings": packings,
        "curves": curves,
        "seconds": time.perf_counter() - started,
    }


def dem_evaluate(runs: dict, observables: Observables, folds, noise: NoiseModel) -> dict:
    """The model scored by its DEM runs (`dem_runs`) instead of its emulator.

    Fit: the mean observables of the runs at the calibrated parameters against the data give chi^2
    (noise: measurement + packing scatter of the measured realisation + that of a mean of R runs),
    AIC, BIC, p-value; the objective (runout MSE) is averaged over the runs. Held out: each fold's
    runs at the parameters fitted without it, on the held-out outputs only.
    """
    model = runs["model"]
    target = observables.measured
    runout = observables.kind == "runout"
    n_packings = len(runs["packings"])
    sigma = np.sqrt(noise.measurement**2 + noise.packing**2 * (1 + 1 / n_packings))
    mean = runs["fit"].mean(axis=0)
    chi2 = float(np.sum(((mean - target) / sigma) ** 2))
    heldout_chi2, squared, folds_out = 0.0, [], []
    for fold, theta_k, fold_runs in zip(folds, runs["fold_theta"], runs["folds"]):
        fold_mean = fold_runs.mean(axis=0)
        fold_chi2 = float(np.sum(((fold_mean[fold.held] - target[fold.held]) / sigma[fold.held]) ** 2))
        heldout_chi2 += fold_chi2
        squared += list((fold_mean[fold.held & runout] - target[fold.held & runout]) ** 2)
        folds_out.append(
            {
                "held_out": fold.description,
                "chi2": fold_chi2,
                "parameters": dict(zip(model.parameter_names, map(float, theta_k))),
            }
        )
    objective = [runout_mse(r[runout], target[runout]) for r in runs["fit"]]
    result = {
        "parameters": dict(zip(model.parameter_names, map(float, runs["theta"]))),
        "packings": runs["packings"],
        "chi2": chi2,
        "n_data": observables.size,
        "n_parameters": model.n_parameters,
        "p_value": p_value(chi2, model.n_parameters, observables.size),
        "aic": aic(chi2, model.n_parameters),
        "bic": bic(chi2, model.n_parameters, observables.size),
        "objective": float(np.mean(objective)),
        "objective_per_packing": objective,
        "heldout_chi2": heldout_chi2,
        "n_heldout": int(sum(int(fold.held.sum()) for fold in folds)),
        "heldout_mse": float(np.mean(squared)) if squared else math.nan,
        "heldout_folds": folds_out,
        "observed_mean": mean.tolist(),
        "sigma": sigma.tolist(),
        "curves": runs["curves"],
        "seconds": runs["seconds"],
    }
    log.info(
        "DEM score of %s: chi2 %.1f, BIC %.1f, held-out chi2 %.1f, objective %.4g",
        model.name,
        chi2,
        result["bic"],
        heldout_chi2,
        result["objective"],
    )
    return result


def _thin_curve(trajectory, runout: RunoutMethod) -> list:
    """[t/t* list, L* list] of a run's runout curve as the diagnosis reads it, every other frame (for the figure)."""
    t, runout = runout.curve(trajectory)
    return [t[::2].round(4).tolist(), runout[::2].round(4).tolist()]


# -- the whole diagnosis -------------------------------------------------------------------------------------
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
    dem_top: int = 2  # candidates (best emulator BIC) scored in the DEM
    runout_noise: float | None = None  # std of L* when the file states none
    profile_noise: float | None = None  # std of the deposit height (m)
    assumed_runout_noise: float = 0.1
    assumed_profile_noise: float = 1e-3
    rule: DecisionRule = field(default_factory=DecisionRule)
    seed: int = 0
    runout: RunoutMethod = field(default_factory=RunoutMethod)  # the config's `runout` section

    def models(self) -> list[Model]:
        return [Model()] + [Model(m) for m in get_mechanisms(self.candidates, self.channel_width)]

    @classmethod
    def from_config(cls, section: dict, runout=None) -> DiagnosisSettings:
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
        out = {k: getattr(self, k) for k in self.__dataclass_fields__ if k not in ("simulation", "rule", "runout")}
        out.update(self.simulation.to_dict(), rule=self.rule.to_dict(), runout=self.runout.to_config())
        out["candidates"] = [m.name for m in self.models()[1:]]
        return out

    def library(self, observables: Observables, progress=None) -> Library:
        """The design runs of every model for these observables."""
        return build_library(
            observables, self.models(), self.simulation, self.n_base, self.n_per_mechanism, self.seed, progress
        )


def diagnose(
    columns,
    settings: DiagnosisSettings,
    library: Library | None = None,
    runner: DEMRunner | None = None,
    data_warnings=(),
    name: str = "",
) -> dict:
    """The diagnosis of measured `columns` (list of MeasuredColumn) as a JSON-ready dict.

    library: design runs for these columns (built here when None; not modified); runner: a
    DEMRunner for them (keeps settled packings between calls). data_warnings: warnings raised
    while reading the data (they forbid naming a cause).
    """
    started = time.perf_counter()
    observables = Observables(columns, settings.runout)
    models = settings.models()
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
    if settings.n_packings > len(settings.simulation.packing_seeds):
        raise DiagnosisError(
            f"n_packings = {settings.n_packings} exceeds the {len(settings.simulation.packing_seeds)} "
            "packing seeds: repeated runs would repeat a packing, not sample the scatter"
        )
    noise, notes = noise_model(
        observables,
        library,
        settings.runout_noise,
        settings.profile_noise,
        settings.assumed_runout_noise,
        settings.assumed_profile_noise,
    )
    notes += check_data(observables, library, models, noise)
    sigma = noise.total
    folds = held_out_folds(observables)
    library = library.copy()  # runs added while refining belong to these data, not to the shared library
    by_name = {m.name: m for m in models}

    def score(model_name):
        model = by_name[model_name]
        emulator = library.emulator(model, settings.seed + models.index(model))
        return score_model(model, emulator, observables, sigma, folds, seed=settings.seed)

    final = {m.name: score(m.name) for m in models}
    for round_ in range(settings.n_rounds):
        scores = final  # the emulator optima this round runs in the DEM (reported with its DEM scores)
        leading = sorted((scores[m.name] for m in models[1:]), key=lambda s: s.bic)[: settings.dem_top]
        runs = {
            n: dem_runs(runner, by_name[n], scores[n], folds, settings.n_packings, round_ * settings.n_packings)
            for n in ["base"] + [s.model for s in leading]
        }
        # the runs join their models' emulators (exact there from now on), and their repeats on
        # different packings join the estimate of the packing scatter
        for n, r in runs.items():
            for theta, observed in [(r["theta"], r["fit"])] + list(zip(r["fold_theta"], r["folds"])):
                for packing, one in zip(r["packings"], observed):
                    library.add_runs(
                        by_name[n], theta, one, packing, r["seconds"] / (len(r["folds"]) + 1) / len(observed)
                    )
        noise, _ = noise_model(
            observables,
            library,
            settings.runout_noise,
            settings.profile_noise,
            settings.assumed_runout_noise,
            settings.assumed_profile_noise,
        )
        sigma = noise.total
        # rescored on the emulators that now hold these runs: the next round's optima, and after
        # the last round the emulators' final word, which the DEM ranking must agree with
        final = {m.name: score(m.name) for m in models}
    dem = {n: dem_evaluate(r, observables, folds, noise) for n, r in runs.items()}
    emulator_best = min((final[m.name] for m in models[1:]), key=lambda s: s.bic).model
    cause, checks, verdict = decide(dem, settings.rule, data_warnings, emulator_best)
    base_dem = dem["base"]
    structure = residual_structure(
        observables, np.array(base_dem["observed_mean"]), np.array(base_dem["sigma"]), by_name["base"].n_parameters
    )
    best = min((n for n in dem if n != "base"), key=lambda n: dem[n]["bic"])
    after = cause if cause != "none" else best
    runout = observables.kind == "runout"
    emulator_notes = [
        f"emulator of {s.model}: leave-one-out error {s.emulator_loo_over_noise:.2g} x the noise (median over outputs)"
        for s in scores.values()
        if s.emulator_loo_over_noise > 1.0
    ]

    for note in notes + emulator_notes:
        warnings.warn(f"{name or 'diagnosis'}: {note}", DiagnosisWarning, stacklevel=2)

    def evidence(model_name):
        d = dem.get(model_name)
        out = {
            "emulator": scores[model_name].to_dict(observables),
            "emulator_final": {
                k: v
                for k, v in final[model_name].to_dict(observables).items()
                if k in ("parameters", "chi2", "bic", "heldout_chi2")
            },
            "dem": None if d is None else {k: v for k, v in d.items() if k != "runs"},
        }
        if model_name != "base":
            source = d if d is not None else out["emulator"]
            reference = base_dem if d is not None else out_base["emulator"]
            out.update(
                scored_in="dem" if d is not None else "emulator",
                delta_bic_vs_base=reference["bic"] - source["bic"],
                heldout_gain=1 - source["heldout_chi2"] / reference["heldout_chi2"],
            )
        return out

    out_base = evidence("base")
    return {
        "name": name,
        "cause": cause,
        "verdict": verdict,
        "checks": checks,
        "decision_rule": settings.rule.to_dict(),
        "simulator": {
            "description": SIMULATOR,
            "engine": "builtin",
            "gns_used": False,
            "size_scale": settings.simulation.size_scale,
            "design_runs": {n: int(np.sum(r.stage != "refine")) for n, r in library.runs.items()},
            "design_dem_seconds": float(sum(r.seconds[r.stage != "refine"].sum() for r in library.runs.values())),
            "refinement_runs": int(sum(np.sum(r.stage == "refine") for r in library.runs.values())),
            "scored_in_dem": list(dem),
            "packings_per_dem_score": settings.n_packings,
            "rounds": settings.n_rounds,
        },
        "settings": settings.to_dict(),
        "columns": [
            {
                "name": c.name,
                "material": c.material,
                "aspect_ratio": c.aspect_ratio,
                "L_i": c.L_i,
                "source": c.source,
                "n_runout": len(c.t_over_tstar),
                "n_profile": 0 if c.profile_x is None else len(c.profile_x),
            }
            for c in observables.columns
        ],
        "observables": {
            "labels": [list(label) for label in observables.labels],
            "measured": observables.measured.tolist(),
            "noise_measurement": noise.measurement.tolist(),
            "noise_packing": noise.packing.tolist(),
            "noise_total": sigma.tolist(),
            "noise_source": noise.source,
        },
        "folds": [f.description for f in folds],
        "residuals": structure,
        "base": out_base,
        "candidates": {m.name: evidence(m.name) for m in models[1:]},
        "extended": None if cause == "none" else {"model": cause, **evidence(cause)},
        "best_candidate": best,
        "errors": {
            "compared_model": after,
            "fit_mse": {"before": base_dem["objective"], "after": dem[after]["objective"]},
            "heldout_mse": {"before": base_dem["heldout_mse"], "after": dem[after]["heldout_mse"]},
            "fit_chi2": {"before": base_dem["chi2"], "after": dem[after]["chi2"]},
            "heldout_chi2": {"before": base_dem["heldout_chi2"], "after": dem[after]["heldout_chi2"]},
            "note": (
                f"DEM runs ({settings.n_packings} packings) at the calibrated parameters; MSE = the runout "
                f"objective over {int(runout.sum())} points; held out: "
                f"{'; '.join(f.description for f in folds)}, each predicted from a fit without it"
            ),
        },
        "warnings": list(data_warnings) + notes + emulator_notes,
        "seconds": time.perf_counter() - started,
    }


# Settings that change the design runs (the library); the others only change the analysis. Read by
# workflow/rules/diagnosis.smk (the library rule's params) and pipeline/diagnosis.py.
LIBRARY_SETTINGS = ("size_scale", "packing_seeds", "candidates", "channel_width", "n_base", "n_per_mechanism", "seed")
