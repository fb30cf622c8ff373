"""The diagnosis' contenders judged by what they predict: each DEM-scored model at its diagnosis fit,
simulated at other aspect ratios and held against the experimental scaling of dry column collapse
(calibration.scaling_laws), and `calibration.model: auto` choosing by the fit and that check together.

One curve of a few points barely tells mechanisms apart (quartz: cohesion and side-wall friction
within a BIC of 8), yet they predict other columns very differently: a cohesion that holds a tall
column back also holds a short one still. The law is a stated expectation with a stated tolerance,
so it enters as pseudo-data: law_chi2 = sum over a of (ln(predicted / law) / law_log_std)^2, the
predicted final runout the mean over packings. How far each candidate's curve moves when the grains
get finer (calibration/grain_shift.py: its fit run at the calibration's grain size and at the
target's, in units of the data's noise) enters the same way, as the part of the answer that will
not transfer. A contender's combined score is its DEM BIC on the measured curve plus law_chi2 plus
that transfer chi^2; the lowest combined score among the candidate mechanisms is calibrated, or,
where candidates lie within the decision margin of it (6, the diagnosis' between candidates), the
first of them whose parameters are all physical.
The base model is predicted too, for contrast (a 2D disc model runs out like discs, not like sand),
but not chosen here: whether a mechanism is needed at all is the diagnosis' BIC test. Pairs of
mechanisms join the candidates (`pairs`: by default the two best single candidates together), each
fitted in the DEM from its better member's fit and scored by a BIC on the diagnosis' terms
(calibration.pairs), so that a pair of physical values can beat one effective value.

The law is that of dry, cohesionless grains in a quasi-2D channel; for a material that is not
(a cohesive powder, a wet sand) switch the check off (`calibration.scaling_check: false`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from calibration.calibrated import VALIDATION_SEED0, CalibrationError, diagnosis_parameters
from calibration.decision import DecisionRule
from calibration.design_runs import SimulationSettings
from calibration.diagnosis_result import Diagnosis
from calibration.grain_shift import GrainShift, grain_shift
from calibration.measured_column import MeasuredColumn
from calibration.mechanisms import MechanismError, get_mechanisms, plausible_for
from calibration.model import Model, model_named
from calibration.pairs import PairFit, fit_pair
from calibration.prediction import predict
from calibration.scaling_laws import QUASI_2D_SOURCE, ScalingCheck, check_scaling
from dem.atomic import StrPath, write_json
from dem.runout import RunoutMethod

LAW_LOG_STD = 0.25  # default tolerance of the law, in ln(L*): a prediction 25% off costs one unit of chi^2
# combined scores closer than this are not told apart (the diagnosis' BIC margin between candidates)
DECISION_MARGIN = DecisionRule().min_delta_bic_vs_runner_up


@dataclass
class Contender:
    """One model of the diagnosis at its fit, predicted across a.

    model: "base", a mechanism or a pair ("a+b"); parameters {name: value} (the diagnosis' DEM-scored
    fit, a pair's its own DEM fit); bic: its DEM BIC on the measured data; runout_each [packings][A],
    height_each [packings][A]: final L* and H_f / L_i per packing (None where a run failed);
    scaling: the check of their means per a; law_chi2: sum over the a that ran of
    (ln(mean / law) / law_log_std)^2; plausibility: each mechanism's fitted value against its
    physical range in words ("" for the base model); physical: every one inside; pair_fit: how a
    pair was fitted (calibration.pairs.PairFit; None for the diagnosis' own models); switched_off:
    the mechanisms of a pair its fit leaves off (Mechanism.switched_on): such a pair is its other
    member at another point, reported but never chosen; grain_shift: its curve's move with the
    grain size (calibration.grain_shift; None: not measured, the base model or no finer scale)."""

    model: str
    parameters: dict[str, float]
    bic: float
    runout_each: list[list[float | None]]
    height_each: list[list[float | None]]
    scaling: ScalingCheck
    law_chi2: float
    plausibility: str
    physical: bool
    pair_fit: PairFit | None = None
    switched_off: list[str] = field(default_factory=list)
    grain_shift: GrainShift | None = None

    @property
    def transfer_chi2(self) -> float:
        """The move of its curve with the grain size in chi^2 units (0 where not measured)."""
        return 0.0 if self.grain_shift is None or self.grain_shift.chi2 is None else self.grain_shift.chi2

    @property
    def combined(self) -> float:
        """The DEM BIC plus the law's chi^2 plus the transfer's: what `auto` minimises over the candidates."""
        return self.bic + self.law_chi2 + self.transfer_chi2

    def to_dict(self) -> dict:
        return dict(asdict(self), transfer_chi2=self.transfer_chi2, combined=self.combined)

    @classmethod
    def from_dict(cls, data: dict) -> Contender:
        fields = {k: v for k, v in data.items() if k not in ("combined", "transfer_chi2")}
        fields["scaling"] = ScalingCheck(**fields["scaling"])
        if fields.get("pair_fit") is not None:
            fields["pair_fit"] = PairFit(**fields["pair_fit"])
        if fields.get("grain_shift") is not None:
            fields["grain_shift"] = GrainShift.from_dict(fields["grain_shift"])
        return cls(**fields)


@dataclass
class DecidingColumn:
    """The column that would tell the two best contenders apart: the aspect ratio [-] (at the measured
    L_i [m]) where their mean predicted final L* differ most relative to the packing scatter.

    models: the two contenders (lowest combined score first); runout: their mean final L* there;
    scatter: the pooled std of one packing's final L* there, over every contender's packings (None
    with one packing each: the difference alone then ranks the a); separation: the difference over
    the std of a difference of two means, sqrt(scatter^2 (1/n_1 + 1/n_2)) (None without a scatter)."""

    aspect_ratio: float
    L_i: float
    models: list[str]
    runout: list[float]
    scatter: float | None
    separation: float | None


@dataclass
class ContenderChoice:
    """contenders.json: every DEM-scored model of the diagnosis side by side, and the choice.

    contenders [models], the base model first; chosen: the candidate of lowest combined score;
    by_fit: the candidate of lowest BIC alone (the diagnosis' best); law_log_std: the law's
    tolerance used; seeds [packings]; seconds: the DEM time of the predictions."""

    name: str
    contenders: list[Contender]
    chosen: str
    by_fit: str
    law_log_std: float
    law: str
    seeds: list[int]
    seconds: float
    L_i: float | None = None  # m, the measured column's, at which every contender is predicted
    deciding: DecidingColumn | None = None  # where the two best would differ most (deciding_column)
    # the DEM runs and seconds of the diagnosis whose fits these are (a pair's fit adds its own)
    diagnosis_runs: int = 0
    diagnosis_seconds: float = 0.0

    def contender(self, model: str) -> Contender:
        return next(c for c in self.contenders if c.model == model)

    @property
    def why(self) -> str:
        """The choice in words, with the fit and the law's share of it."""
        chosen, fit = self.contender(self.chosen), self.contender(self.by_fit)

        def misses(c: Contender) -> str:
            return f"off the law by a factor of {math.exp(c.scaling.runout_error):.2g} (RMS over a)"

        def parts(c: Contender) -> str:
            moved = f" + transfer {c.transfer_chi2:.1f}" if c.grain_shift is not None else ""
            return f"{c.combined:.1f} (BIC {c.bic:.1f} + law {c.law_chi2:.1f}{moved})"

        weighed = f"the law of {self.law} as pseudo-data (tolerance {self.law_log_std:g} in ln L*)"
        shifts = [c.grain_shift for c in self.contenders if c.grain_shift is not None]
        if shifts:
            coarse, fine = shifts[0].size_scales
            weighed += (
                f" and each curve's move from size_scale {coarse:g} to {fine:g} at the same parameters, in units "
                "of the data's noise (what will not transfer)"
            )
        lowest = ranked_candidates(self.contenders)[0]
        if lowest.model != self.chosen:  # the physical one of candidates the data do not tell apart
            return (
                f"{lowest.model} scores lowest on fit, law and transfer together ({weighed}): {parts(lowest)}, "
                f"but {self.chosen} scores {parts(chosen)}, within the margin of {DECISION_MARGIN:g} the data do "
                f"not tell apart, and its parameters are physical where {lowest.model}'s are effective: "
                f"{self.chosen} is calibrated. Its predictions across a are {misses(chosen)}."
            )
        if self.chosen == self.by_fit:
            return (
                f"{self.chosen} fits the measured curve best (DEM BIC {chosen.bic:.1f}) and its predictions "
                f"across a are {misses(chosen)}; no other candidate does better on fit, law and transfer together "
                f"({weighed}): it scores {parts(chosen)}."
            )
        return (
            f"{self.by_fit} fits the measured curve best (BIC {fit.bic:.1f}, {chosen.bic - fit.bic:.1f} below "
            f"{self.chosen}), but its predictions across a are {misses(fit)}, {self.chosen}'s {misses(chosen)}: "
            f"with {weighed}, {self.chosen} scores {parts(chosen)} against {parts(fit)}, so {self.chosen} is "
            "calibrated."
        )

    def to_dict(self) -> dict:
        return dict(asdict(self), contenders=[c.to_dict() for c in self.contenders], why=self.why)

    @classmethod
    def from_dict(cls, data: dict) -> ContenderChoice:
        fields = {k: v for k, v in data.items() if k != "why"}
        fields["contenders"] = [Contender.from_dict(c) for c in data["contenders"]]
        if fields.get("deciding") is not None:
            fields["deciding"] = DecidingColumn(**fields["deciding"])
        return cls(**fields)

    def to_json(self, path: StrPath) -> None:
        write_json(path, self.to_dict())

    @classmethod
    def read(cls, path: StrPath) -> ContenderChoice:
        return cls.from_dict(json.loads(Path(path).read_text()))


def mean_or_none(values: Sequence[float | None]) -> float | None:
    """Mean of the finite values; None when none is."""
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def law_chi2(check: ScalingCheck, law_log_std: float) -> float:
    """sum over the a that ran of (ln(predicted / law) / law_log_std)^2; inf when none ran."""
    ratios = [r for r in check.runout_log_ratio if r is not None]
    return float(sum((r / law_log_std) ** 2 for r in ratios)) if ratios else math.inf


def score_contender(
    model: Model,
    parameters: dict[str, float],
    bic: float,
    aspect_ratios: Sequence[float],
    runout_each: Sequence[Sequence[float | None]],
    height_each: Sequence[Sequence[float | None]],
    law_log_std: float,
    pair_fit: PairFit | None = None,
) -> Contender:
    """A contender from its predictions per packing [packings][A] (final L*, H_f / L_i)."""
    runout = [mean_or_none(column) for column in zip(*runout_each)]
    height = [mean_or_none(column) for column in zip(*height_each)]
    check = check_scaling(aspect_ratios, runout, height)
    plausibility = "; ".join(m.plausibility(parameters[m.parameter]) for m in model.mechanisms)
    physical = all(m.is_plausible(parameters[m.parameter]) for m in model.mechanisms)
    pair = len(model.mechanisms) > 1
    switched_off = [m.name for m in model.mechanisms if pair and not m.switched_on(parameters)]
    return Contender(
        model=model.name,
        parameters={k: float(v) for k, v in parameters.items()},
        bic=float(bic),
        runout_each=[list(r) for r in runout_each],
        height_each=[list(h) for h in height_each],
        scaling=check,
        law_chi2=law_chi2(check, law_log_std),
        plausibility=plausibility,
        physical=physical,
        pair_fit=pair_fit,
        switched_off=switched_off,
    )


def ranked_candidates(contenders: Sequence[Contender]) -> list[Contender]:
    """The candidate mechanisms (every contender but "base" and a pair fitted with a mechanism off),
    lowest combined score first (BIC breaks ties)."""
    candidates = (c for c in contenders if c.model != "base" and not c.switched_off)
    return sorted(candidates, key=lambda c: (c.combined, c.bic))


def choose(contenders: Sequence[Contender], margin: float = DECISION_MARGIN) -> tuple[str, str]:
    """(chosen, by_fit): the candidate of lowest combined score, except that among the candidates
    within `margin` of it, which the data do not tell apart, the first whose every parameter lies in
    its physical range is chosen; and the candidate of lowest BIC."""
    ranked = ranked_candidates(contenders)
    if not ranked:
        raise CalibrationError("scaling check: the diagnosis scored no candidate mechanism in the DEM")
    tied = [c for c in ranked if c.combined - ranked[0].combined < margin]
    chosen = next((c for c in tied if c.physical), ranked[0])
    return chosen.model, min(ranked, key=lambda c: c.bic).model


def deciding_column(contenders: Sequence[Contender], L_i: float) -> DecidingColumn | None:
    """Of the two candidate mechanisms of lowest combined score, the aspect ratio at which their mean
    final L* differ most in units of the packing scatter (DecidingColumn); None with fewer than two
    candidates or no a where both ran."""
    ranked = ranked_candidates(contenders)
    if len(ranked) < 2:
        return None
    first, second = ranked[:2]
    best: tuple[float, int, float | None, float | None] | None = None
    for k in range(len(first.scaling.aspect_ratios)):
        m1, m2 = first.scaling.final_runout[k], second.scaling.final_runout[k]
        if m1 is None or m2 is None:
            continue
        scatter = pooled_scatter(contenders, k)
        n1, n2 = (sum(1 for each in c.runout_each if each[k] is not None) for c in (first, second))
        separation = None if scatter is None or scatter == 0 else abs(m1 - m2) / (scatter * math.sqrt(1 / n1 + 1 / n2))
        rank = abs(m1 - m2) if separation is None else separation
        if best is None or rank > best[0]:
            best = (rank, k, scatter, separation)
    if best is None:
        return None
    _, k, scatter, separation = best
    return DecidingColumn(
        aspect_ratio=first.scaling.aspect_ratios[k],
        L_i=float(L_i),
        models=[first.model, second.model],
        runout=[float(first.scaling.final_runout[k]), float(second.scaling.final_runout[k])],
        scatter=scatter,
        separation=separation,
    )


def pooled_scatter(contenders: Sequence[Contender], k: int) -> float | None:
    """The pooled std of one packing's final L* about its contender's mean at aspect ratio index k,
    over every contender with at least two packings that ran there; None where none has."""
    squares, dof = 0.0, 0
    for c in contenders:
        values = [each[k] for each in c.runout_each if each[k] is not None]
        if len(values) >= 2:
            squares += float(np.sum((np.array(values) - np.mean(values)) ** 2))
            dof += len(values) - 1
    return math.sqrt(squares / dof) if dof else None


def contender_models(diagnosis: Diagnosis, channel_width: float) -> list[Model]:
    """The base model and every candidate the diagnosis scored in the DEM, base first."""
    names = [n for n, e in diagnosis.candidates.items() if e.dem is not None]
    return [Model()] + [Model(m) for m in get_mechanisms(names, channel_width)]


def contender_pairs(pairs: str | Sequence[Sequence[str]], singles: Sequence[Contender]) -> list[list[str]]:
    """The pairs of mechanisms to fit: `pairs` as given ([[a, b], ...]), or "auto": the two single
    candidates of lowest combined score together (none with fewer than two). CalibrationError
    naming calibration.contender_pairs for a pair that is not two different known mechanisms."""
    if pairs == "auto":
        ranked = ranked_candidates(singles)
        return [[ranked[0].model, ranked[1].model]] if len(ranked) >= 2 else []
    out = []
    for k, pair in enumerate(pairs):
        try:
            if isinstance(pair, str) or len(pair) != 2:
                raise MechanismError(f"{pair!r} is not a pair of two mechanisms")
            Model(*get_mechanisms(list(pair)))
        except MechanismError as exc:
            raise CalibrationError(f"calibration.contender_pairs[{k}]: {exc}") from None
        out.append(list(pair))
    return out


def check_contenders(
    diagnosis: Diagnosis,
    column: MeasuredColumn,
    settings: SimulationSettings,
    aspect_ratios: Sequence[float],
    runout: RunoutMethod,
    dem_config: dict | None,
    *,
    channel_width: float = 0.01,
    n_packings: int = 2,
    law_log_std: float = LAW_LOG_STD,
    name: str = "",
    progress: Callable[[float], None] | None = None,
    plausible_ranges: Mapping[str, Mapping[str, Mapping]] | None = None,
    pairs: str | Sequence[Sequence[str]] = (),
    pair_packings: int = 4,
    pair_rounds: int = 3,
    finer_size_scale: float | None = None,
) -> ContenderChoice:
    """Predict every DEM-scored model of `diagnosis` at its fit on `column`'s material and L_i at
    each aspect ratio, on n_packings packings (seeds VALIDATION_SEED0 + k, calibration.prediction),
    score each against the quasi-2D law and choose (module docstring). `pairs` (contender_pairs)
    join them, each fitted first (calibration.pairs.fit_pair: pair_packings confirmation packings,
    pair_rounds Gauss-Newton steps). With finer_size_scale (finer than `settings`'), every candidate's
    curve on the measured column is run there too, on the same packings (calibration.grain_shift),
    and its move weighed. Each mechanism's parameter is judged against its plausible range for the
    column's material (plausible_for over plausible_ranges, the config's calibration.plausible_ranges)."""
    if finer_size_scale is not None and not finer_size_scale < settings.size_scale:
        raise CalibrationError(
            f"the contenders' transfer: size_scale {finer_size_scale:g} is not finer than {settings.size_scale:g}"
        )
    noise = [
        float(sigma)
        for (name, kind, _), sigma in zip(diagnosis.observables.labels, diagnosis.observables.noise_total)
        if name == column.name and kind == "runout"
    ]
    if not law_log_std > 0:
        raise CalibrationError(f"calibration.scaling_log_std: {law_log_std!r} must be positive")
    material = column.material_properties.name

    def judged(model: Model) -> Model:
        return Model(*(plausible_for(m, material, plausible_ranges or {}) for m in model.mechanisms))

    singles = [judged(m) for m in contender_models(diagnosis, channel_width)]
    seeds = [VALIDATION_SEED0 + k for k in range(n_packings)]
    contenders, seconds, done = [], [0.0], [0]
    # progress in packings' worth of prediction runs, a pair's fit counted as two of them (auto: one
    # pair where two candidates were scored)
    n_pairs = (len(singles) > 2) if pairs == "auto" else len(pairs)
    n_shifts = (len(singles) - 1 + n_pairs) if finer_size_scale is not None else 0
    total = (len(singles) + n_pairs) * len(seeds) + 2 * n_pairs + 2 * n_shifts

    def predicted(model: Model, theta: Sequence[float], bic: float, pair_fit: PairFit | None = None) -> Contender:
        runouts, heights = [], []
        for seed in seeds:
            within = None if progress is None else (lambda f, d=done[0]: progress(min((d + f) / total, 1.0)))
            p = predict(model, column, theta, settings, aspect_ratios, runout, dem_config, seed=seed, progress=within)
            runouts.append(p.final_runout)
            heights.append(p.height_over_L_i)
            seconds[0] += p.seconds
            done[0] += 1
        parameters = dict(zip(model.parameter_names, map(float, theta)))
        contender = score_contender(model, parameters, bic, aspect_ratios, runouts, heights, law_log_std, pair_fit)
        if finer_size_scale is not None and model.mechanisms:  # the base model is never chosen: not run
            within = None if progress is None else (lambda f, d=done[0]: progress(min((d + 2 * f) / total, 1.0)))
            contender.grain_shift = grain_shift(
                model, column, theta, settings, finer_size_scale, runout, dem_config, noise, len(seeds), within
            )
            seconds[0] += contender.grain_shift.seconds
            done[0] += 2
        return contender

    for model in singles:
        evidence = diagnosis.base if model.name == "base" else diagnosis.candidates[model.name]
        contenders.append(predicted(model, diagnosis_parameters(diagnosis, model), evidence.dem.bic))
    to_fit = contender_pairs(pairs, contenders)
    for pair_names in to_fit:
        pair = judged(Model(*get_mechanisms(pair_names, channel_width)))
        members = [c for c in ranked_candidates(contenders) if c.model in pair_names and c.pair_fit is None]
        if not members:
            raise CalibrationError(
                f"calibration.contender_pairs: the diagnosis scored neither of {pair_names} in the DEM, so no start"
            )
        start = judged(model_named(members[0].model, channel_width))
        within = None if progress is None else (lambda f, d=done[0]: progress(min((d + 2 * f) / total, 1.0)))
        fit = fit_pair(
            pair,
            start,
            list(members[0].parameters.values()),
            diagnosis,
            column,
            runout,
            dem_config,
            pair_packings,
            pair_rounds,
            within,
        )
        done[0] += 2
        seconds[0] += fit.seconds
        theta = [fit.parameters[n] for n in pair.parameter_names]
        contenders.append(predicted(pair, theta, fit.bic, fit))
    chosen, by_fit = choose(contenders)
    return ContenderChoice(
        name=name,
        contenders=contenders,
        chosen=chosen,
        by_fit=by_fit,
        law_log_std=float(law_log_std),
        law=QUASI_2D_SOURCE,
        seeds=seeds,
        seconds=seconds[0],
        L_i=float(column.L_i),
        deciding=deciding_column(contenders, column.L_i),
        diagnosis_runs=diagnosis.simulator.dem_runs,
        diagnosis_seconds=float(diagnosis.seconds),
    )


def resolve_by_prediction(model: Model, why: str, choice: ContenderChoice, channel_width: float) -> tuple[Model, str]:
    """(Model, why) of `auto` once the contenders' predictions are in: `model`/`why` as the diagnosis
    alone resolved them (calibration.calibrated.resolve_model), replaced where fit and law together
    choose another candidate."""
    if choice.chosen == model.name:
        return model, f"{why} Judged by its predictions across a too: {choice.why}"
    return model_named(choice.chosen, channel_width), (
        f"auto: by the measured curve alone the diagnosis chose {model.name}; judged by what each contender "
        f"predicts across a as well, {choice.chosen} is calibrated. {choice.why}"
    )
