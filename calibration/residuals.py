"""The measured data against the simulation: the noise every value carries, checks that the data can
be judged, the held-out folds, and the structure of a calibrated model's residuals.

Noise (`noise_model`). Each measured value = DEM response + packing scatter + measurement noise. The
measurement noise is the file's std (runout) or a stated value (a missing one is assumed and said
so); the packing scatter (the measured column is one random packing, a model's mean is not) is
pooled over every set of runs repeated on different packings. Variances add. The same noise serves
every model, so their chi^2 values compare.

Bad input (`check_data`, `noise_model`): fewer than 3 runout points in a column, a zero or negative
noise level, a runout that looks like metres or lies far above (UNITS_FACTOR x) everything the
simulator produced: a DiagnosisError.

Held-out folds (`held_out_folds`): one column at a time where there are several, else one phase of
the runout at a time.

Residuals (`residual_structure` -> `ResidualStructure`) of a calibrated model (in the diagnosis:
the base model's DEM runs): chi^2 against the noise, grouped by time phase (the paper's free-fall
t/t* <= 1, spreading 1-2.5, stopping > 2.5), column and deposit region, a runs test on the signs;
said in plain words (and drawn by calibration/diagnosis_report.py).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2 as chi2_distribution
from scipy.stats import norm

from calibration.design_runs import Library
from calibration.measured_column import MeasuredColumn
from calibration.model import Model
from calibration.observables import Observables

# The paper's three phases of a collapse (Jiang et al. 2024, section 4.1).
PHASES = (
    ("free-fall phase (t/t* <= 1)", 0.0, 1.0),
    ("spreading phase (1 < t/t* <= 2.5)", 1.0, 2.5),
    ("stopping phase (t/t* > 2.5)", 2.5, math.inf),
)
# A runout more than this many times the highest design run is read as wrong units (mm, per cent:
# factors of 20 to 1000), not as data beyond the design.
UNITS_FACTOR = 3.0
# A curve "grows" when its least-squares slope over t/t* is this many standard errors above zero,
# the errors from its own scatter about the line (growing_curve).
GROWTH_T = 3.0
BIAS_Z = 2.0  # |sum of z| / sqrt(n) above this: a group's residuals are biased
# What the diagnosis needs of the data (check_data). Per column, a curve, not a point: a line through two
# points leaves no scatter to judge its growth by (growing_curve), nor a misfit after the fit of friction and
# restitution. Per file, this many measured values beyond the parameters of its largest model, or no
# chi^2 and BIC are left to compare models with. pipeline.config checks both before any job runs.
MIN_RUNOUT_POINTS = 3
MIN_SPARE_VALUES = 3


class DiagnosisError(ValueError):
    """The data cannot be diagnosed; the message says which column or setting is wrong."""


# -- noise ------------------------------------------------------------------------------------------
@dataclass
class NoiseModel:
    """Per output [q]: measurement noise std and packing scatter std (their variances add), and the
    correlation factor sqrt(n / n_eff) >= 1 by which a profile point's std is widened because its
    neighbours within a correlation length carry the same grains (1 for runout points)."""

    measurement: np.ndarray
    packing: np.ndarray
    source: str
    correlation: np.ndarray | None = None  # [q]; None: every output independent

    def __post_init__(self):
        if self.correlation is None:
            self.correlation = np.ones_like(np.asarray(self.measurement, float))

    @property
    def total(self) -> np.ndarray:
        """[q] std of each measured value about the model's mean response, correlation included."""
        return np.sqrt(self.measurement**2 + self.packing**2) * self.correlation

    @property
    def n_effective(self) -> int:
        """Independent measured values: each output counts 1 / correlation^2 (a column's profile
        counts its effective number of points, not its row count)."""
        return int(round(float(np.sum(1.0 / self.correlation**2))))


def profile_resolution_std(column: MeasuredColumn, size_scale: float) -> float:
    """Std (m) of the discrepancy between a model's and the measurement's deposit heights that comes
    from their grain sizes alone: |d_model - d_measured| / 2.

    A height is the top of the highest grain in a bin, so a deposit a few grains thick is built of
    whole grains: a model of coarser grains (d_model = size_scale x the material's diameter) piles
    it in thicker layers and reads it on average about half the difference of the diameters higher
    (the offset seen in data from a finer solver). That is the model's resolution, not
    its physics, so it is counted as noise, not left for a mechanism to absorb. The grain-scale
    roughness of the surface itself is already in the packing scatter of repeated runs.
    """
    d_model = column.material_properties.diameter * size_scale
    return abs(d_model - column.measured_diameter) / 2.0


def profile_correlation(column: MeasuredColumn, size_scale: float) -> float:
    """sqrt(n / n_eff) of a column's profile: points closer than a correlation length share grains.

    A reading at x sees the grains with centres within half a bin of x, and each grain reaches a
    radius further, in the model and in the measurement, so two readings closer than
    bin + d_model (m) are not independent: the profile spanning S (m) holds n_eff = min(n, S / (bin
    + d_model) + 1) independent points. A profile sampled ten times finer therefore carries the same
    evidence, and cannot outvote the runout by its row count.
    """
    n = len(column.profile_x)
    length = column.profile_bin + column.material_properties.diameter * size_scale
    span = float(column.profile_x[-1] - column.profile_x[0])
    return math.sqrt(n / min(n, span / length + 1.0))


def noise_model(
    observables: Observables,
    library: Library,
    runout_noise: float | None = None,
    profile_noise: float | None = None,
    assumed_runout_noise: float = 0.1,
    assumed_profile_noise: float = 1e-3,
) -> tuple[NoiseModel, list[str]]:
    """(NoiseModel, warnings [str]).

    Runout noise: the file's std where given, else `runout_noise` (std of L*), else
    `assumed_runout_noise` with a warning. Profile noise (std, m): `profile_noise`, else
    `assumed_profile_noise` with a warning (the CSV reader keeps no profile std).
    """
    notes = []
    for value, what in (
        (runout_noise, "runout_noise"),
        (profile_noise, "profile_noise"),
        (assumed_runout_noise, "assumed_runout_noise"),
        (assumed_profile_noise, "assumed_profile_noise"),
    ):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise DiagnosisError(
                f"{what} = {value}: a noise level must be a positive standard deviation "
                "(zero would claim an exact measurement and make any misfit 'decisive')"
            )
    stated = observables.measured_std.copy()
    kind = observables.kind
    sources = set()
    for c in observables.columns:
        rows = (observables.column_index == observables.columns.index(c)) & (kind == "runout")
        if c.runout_std is not None:
            sources.add("runout std from the file")
            continue
        if runout_noise is not None:
            stated[rows] = runout_noise
            sources.add(f"runout std {runout_noise:g} (given)")
        else:
            stated[rows] = assumed_runout_noise
            sources.add(f"runout std {assumed_runout_noise:g} ASSUMED")
            notes.append(
                f"column {c.name!r} ({c.source}) states no runout noise level; assumed std "
                f"{assumed_runout_noise:g} L* - the verdict depends on this assumption"
            )
    correlation = np.ones(len(stated))
    size_scale = float(library.settings["size_scale"])
    for j, c in enumerate(observables.columns):
        rows = (observables.column_index == j) & (kind == "profile")
        if not rows.any():
            continue
        if c.profile_std is not None:
            sources.add("profile std from the file")
        elif profile_noise is not None:
            stated[rows] = profile_noise
            sources.add(f"profile std {profile_noise:g} m (given)")
        else:
            stated[rows] = assumed_profile_noise
            sources.add(f"profile std {assumed_profile_noise:g} m ASSUMED")
            notes.append(f"column {c.name!r}: no profile noise level given; assumed std {assumed_profile_noise:g} m")
        resolution = profile_resolution_std(c, size_scale)
        stated[rows] = np.sqrt(stated[rows] ** 2 + resolution**2)
        correlation[rows] = profile_correlation(c, size_scale)
        sources.add("profile: plus the grain-size discrepancy |d_model - d_measured| / 2, neighbouring bins correlated")
        notes += [f"column {c.name!r}: profile {d}" for d in c.profile_defaults]
    if np.any(~np.isfinite(stated)) or np.any(stated <= 0):
        raise DiagnosisError("measurement noise: a noise level must be a positive standard deviation")
    packing = library.packing_std()
    source = "; ".join(sorted(sources)) + "; plus packing scatter from replicate DEM runs"
    return NoiseModel(stated, packing, source, correlation), notes


# -- input checks ------------------------------------------------------------------------------------
def check_data(observables: Observables, library: Library, models: list[Model], noise: NoiseModel) -> list[str]:
    """Errors for data the diagnosis cannot judge; warnings [str] for doubtful data."""
    largest = max(m.n_parameters for m in models)
    for c in observables.columns:
        if len(c.t_over_tstar) < MIN_RUNOUT_POINTS:
            raise DiagnosisError(
                f"column {c.name!r} ({c.source}): {len(c.t_over_tstar)} runout point(s); the "
                f"diagnosis needs at least {MIN_RUNOUT_POINTS} per column (a curve, not a point)"
            )
    if observables.size < largest + MIN_SPARE_VALUES:
        raise DiagnosisError(
            f"{observables.size} measured values for models of up to {largest} parameters: "
            f"too few to compare models (need at least parameters + {MIN_SPARE_VALUES})"
        )
    # Units. A runout given in metres (L - L_i = L* L_i) is far below every base-model run (which
    # always collapses), grows like a runout, and divided by L_i becomes a plausible L*. (A
    # cohesive column that stands has an L* near zero too, but it does not grow: its points are
    # noise about zero, which can span more than half their peak, so the growth must stand out of
    # the curve's own scatter, growing_curve.) A runout far
    # above every run of every model is wrong units of another kind (mm of L - L_i: 1000 L_i L*,
    # per cent: 100 L*): "far" is more than UNITS_FACTOR times the highest run. Merely above the
    # highest run is data: a few design runs need not reach the edge of a model's box (a hidden
    # floor friction of 0.03 ran 15% beyond the farthest of 5 CI design runs).
    observed = np.concatenate([runs.observed for runs in library.runs.values()])
    base_runs = library.runs["base"].observed
    target, sigma = observables.measured, noise.total
    runout = observables.kind == "runout"
    # Units belong to a file, not to one column: a short cohesive column that barely moves, beside a
    # taller one of the same file that collapses, is data; every column of a file low like that is metres.
    wrong, metres_like = [], {}
    for j, c in enumerate(observables.columns):
        rows = np.flatnonzero(runout & (observables.column_index == j))
        peak, lowest = float(target[rows].max()), float(target[rows].min())
        margin = 3 * float(sigma[rows][np.argmax(target[rows])])
        base_peak = base_runs[:, rows].max(axis=1)
        if (
            peak < base_peak.min() - margin
            and peak - lowest > 0.5 * peak
            and growing_curve(observables.x[rows], target[rows])
            and base_peak.min() / 3 <= peak / c.L_i <= 3 * base_peak.max()
        ):
            metres_like.setdefault(c.source, []).append(
                f"{c.name!r} ({c.source}) peaks at L* = {peak:g}, every base-model run at {base_peak.min():.3g} "
                f"to {base_peak.max():.3g}; divided by L_i = {c.L_i:g} m it would be {peak / c.L_i:.3g}"
            )
        elif peak > UNITS_FACTOR * observed[:, rows].max() + margin:
            wrong.append(
                f"{c.name!r} ({c.source}) peaks at L* = {peak:g}, above every run of every candidate "
                f"model (at most {observed[:, rows].max():.3g}) by more than {UNITS_FACTOR:g}x: check the units of L*"
            )
    notes = []
    for source, why in metres_like.items():
        n_columns = sum(c.source == source for c in observables.columns)
        if len(why) == n_columns:
            wrong.append("; ".join(why) + ": it looks like metres (L - L_i), not L* = (L - L_i)/L_i")
        else:
            notes += [
                f"{w}: read as a column that barely moved (other columns of {source} are not that low)" for w in why
            ]
    if wrong:
        raise DiagnosisError("measured runout the simulator cannot have produced: " + "; ".join(wrong))
    low, high = observed.min(axis=0), observed.max(axis=0)
    outside = (target < low - 3 * sigma) | (target > high + 3 * sigma)
    if np.any(outside):
        k = np.flatnonzero(outside)
        notes.append(
            f"{len(k)} measured value(s) lie outside the range of every simulated model "
            f"({[observables.labels[j] for j in k[:4]]}...): no candidate can reach them"
        )
    return notes


def growing_curve(t: np.ndarray, values: np.ndarray) -> bool:
    """Whether values [K] grow with t [K] beyond their own scatter: the least-squares slope is more
    than GROWTH_T standard errors above zero, the errors from the residuals about the line (so a
    smooth curve grows whatever noise its file states, and noise about a constant does not)."""
    t, values = np.asarray(t, float), np.asarray(values, float)
    if len(t) < 3:
        return bool(values[-1] > values[0])
    dt = t - t.mean()
    slope = float(dt @ (values - values.mean()) / (dt @ dt))
    residual = values - values.mean() - slope * dt
    error = math.sqrt(float(residual @ residual) / (len(t) - 2) / float(dt @ dt))
    return slope > GROWTH_T * error


@dataclass(frozen=True)
class Fold:
    """A held-out fold: the outputs left out of the fit [q] bool, and the columns to simulate for them."""

    description: str
    held: np.ndarray
    columns: tuple


def held_out_folds(observables: Observables) -> list[Fold]:
    """Leave one column out where there are several. With one column, leave one phase of the
    runout out (fit the other phases, predict it); one runout point at a time when the points
    cover a single phase. The deposit profile, if any, stays in the fit of a one-column fold."""
    index, kind, x = observables.column_index, observables.kind, observables.x
    if len(observables.columns) > 1:
        return [
            Fold(f"column {c.name} (a = {c.aspect_ratio:g})", index == j, (j,))
            for j, c in enumerate(observables.columns)
        ]
    runout = kind == "runout"
    folds = []
    for label, low, high in PHASES:
        held = runout & (x > low) & (x <= high) if low > 0 else runout & (x <= high)
        if held.any():
            folds.append(Fold(label, held, (0,)))
    if len(folds) < 2:
        folds = [Fold(f"t/t* = {x[k]:g}", np.arange(observables.size) == k, (0,)) for k in np.flatnonzero(runout)]
    return folds


# -- residual structure ----------------------------------------------------------------------------------
def runs_test(signs: ArrayLike) -> float:
    """One-sided p-value of the Wald-Wolfowitz runs test: few runs of equal sign = structure.

    signs [n] of +1/-1 in order. All one sign: probability 2^(1-n) of that under a fair coin.
    """
    signs = np.asarray(signs)
    n_plus, n_minus = int(np.sum(signs > 0)), int(np.sum(signs < 0))
    n = n_plus + n_minus
    if n < 2:
        return 1.0
    if n_plus == 0 or n_minus == 0:
        return float(2.0 ** (1 - n))
    runs = 1 + int(np.sum(signs[1:] != signs[:-1]))
    mean = 2.0 * n_plus * n_minus / n + 1
    variance = 2.0 * n_plus * n_minus * (2.0 * n_plus * n_minus - n) / (n**2 * (n - 1))
    return float(norm.cdf((runs - mean) / math.sqrt(variance))) if variance > 0 else 1.0


@dataclass(frozen=True)
class ResidualGroup:
    """The residuals of one column in one time phase (runout) or deposit region (profile)."""

    column: str  # column name
    aspect_ratio: float  # of the column
    kind: str  # "runout" | "profile"
    group: str  # the phase or region, in words (PHASES' labels, or "deposit behind/beyond the gate ...")
    n: int  # values in the group
    mean_residual: float  # mean of simulated - measured (L* or m)
    chi2: float  # sum of squared normalised residuals z = residual / sigma
    p_value: float  # P(chi^2 >= chi2) with n degrees of freedom
    bias_z: float  # sum(z) / sqrt(n): ~N(0, 1) when unbiased
    biased: bool  # |bias_z| > BIAS_Z


@dataclass(frozen=True)
class SignRuns:
    """Runs test of one column's runout residual signs."""

    column: str  # column name
    p_value: float  # one-sided runs-test p-value (`runs_test`): small = long runs of one sign


@dataclass(frozen=True, eq=False)
class ResidualStructure:
    """The residuals (simulated - measured) of a calibrated model against the noise, grouped and in words."""

    chi2: float  # sum over all q values of z^2, z = residual / sigma
    dof: int  # degrees of freedom, q - p (at least 1)
    p_value: float  # P(chi^2 >= chi2) with dof degrees of freedom
    groups: list[ResidualGroup]  # by column and time phase or deposit region
    runs_test: list[SignRuns]  # per column
    residual: np.ndarray  # [q] simulated - measured (L* or m)
    z: np.ndarray  # [q] residual / sigma
    summary: str  # plain words

    def to_dict(self) -> dict:
        """JSON-ready, keys in field order (groups and runs tests as dicts, arrays as lists)."""
        return {**asdict(self), "residual": self.residual.tolist(), "z": self.z.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> ResidualStructure:
        """Inverse of `to_dict` (as read back from JSON)."""
        return cls(
            **{
                **data,
                "groups": [ResidualGroup(**g) for g in data["groups"]],
                "runs_test": [SignRuns(**r) for r in data["runs_test"]],
                "residual": np.asarray(data["residual"], float),
                "z": np.asarray(data["z"], float),
            }
        )


def residual_structure(
    observables: Observables, predicted: np.ndarray, sigma: np.ndarray, n_parameters: int
) -> ResidualStructure:
    """Residuals (simulated `predicted` [q] - measured) of a calibrated model with `n_parameters`
    parameters against the noise std `sigma` [q] (L* or m), grouped and put in words."""
    target = observables.measured
    residual = predicted - target
    z = residual / sigma
    chi2 = float(np.sum(z**2))
    dof = max(observables.size - n_parameters, 1)
    p_value = float(chi2_distribution.sf(chi2, dof))
    groups, runs = [], []
    for j, c in enumerate(observables.columns):
        in_column = observables.column_index == j
        runout = in_column & (observables.kind == "runout")
        for label, low, high in PHASES:
            rows = (
                runout & (observables.x > low) & (observables.x <= high)
                if low > 0
                else runout & (observables.x <= high)
            )
            if rows.any():
                groups.append(_group(c, "runout", label, rows, residual, z))
        profile = in_column & (observables.kind == "profile")
        if profile.any():
            near = profile & (observables.x <= c.L_i)
            far = profile & (observables.x > c.L_i)
            for rows, label in (
                (near, "deposit behind the gate (x <= L_i)"),
                (far, "deposit beyond the gate (x > L_i)"),
            ):
                if rows.any():
                    groups.append(_group(c, "profile", label, rows, residual, z))
        runs.append(SignRuns(c.name, runs_test(np.sign(residual[runout]))))
    words = _plain_words(observables, groups, runs, chi2, dof, p_value)
    return ResidualStructure(chi2, dof, p_value, groups, runs, residual, z, words)


def _group(column: MeasuredColumn, kind: str, label: str, rows, residual, z) -> ResidualGroup:
    n = int(rows.sum())
    bias_z = float(np.sum(z[rows]) / math.sqrt(n))
    return ResidualGroup(
        column=column.name,
        aspect_ratio=column.aspect_ratio,
        kind=kind,
        group=label,
        n=n,
        mean_residual=float(np.mean(residual[rows])),
        chi2=float(np.sum(z[rows] ** 2)),
        p_value=float(chi2_distribution.sf(np.sum(z[rows] ** 2), n)),
        bias_z=bias_z,
        biased=abs(bias_z) > BIAS_Z,
    )


def _plain_words(observables, groups: list[ResidualGroup], runs: list[SignRuns], chi2, dof, p_value) -> str:
    """Sentences such as "runout overshoots in the stopping phase in every column, more for a = 2"."""
    sentences = []
    verdict = "within" if p_value >= 0.01 else "beyond"
    sentences.append(
        f"The residuals of the calibrated model are {verdict} the stated noise "
        f"(chi^2 = {chi2:.1f} for {dof} degrees of freedom, p = {p_value:.2g})."
    )
    n_columns = len(observables.columns)
    labels = [label for label, _, _ in PHASES] + [
        "deposit behind the gate (x <= L_i)",
        "deposit beyond the gate (x > L_i)",
    ]
    for label in labels:
        rows = [g for g in groups if g.group == label]
        biased = [g for g in rows if g.biased]
        if not biased:
            continue
        is_runout = biased[0].kind == "runout"
        signs = {np.sign(g.mean_residual) for g in biased}
        unit = (lambda v: f"{v:+.2f} L*") if is_runout else (lambda v: f"{v * 1e3:+.1f} mm")
        words = ("overshoots", "undershoots") if is_runout else ("is higher than measured", "is lower than measured")
        subject = "the simulated runout" if is_runout else "the simulated deposit"
        where = label.split(" (")[0] if is_runout else label
        if len(signs) == 1:
            word = words[0] if signs.pop() > 0 else words[1]
            scope = (
                "in every column"
                if len(biased) == n_columns and n_columns > 1
                else "in column " + ", ".join(f"{g.column}" for g in biased)
            )
            detail = ", ".join(
                f"a = {g.aspect_ratio:g}: {unit(g.mean_residual)}" for g in sorted(biased, key=lambda g: g.aspect_ratio)
            )
            if n_columns == 1:
                scope, detail = "", f"by {unit(biased[0].mean_residual)} on average"
            trend = ""
            if len(biased) > 1:
                by_a = sorted(biased, key=lambda g: g.aspect_ratio)
                sizes = [abs(g.mean_residual) for g in by_a]
                if all(b > a for a, b in zip(sizes, sizes[1:])):
                    trend = ", more for taller columns"
                elif all(b < a for a, b in zip(sizes, sizes[1:])):
                    trend = ", more for shorter columns"
            sentences.append(f"In the {where} {subject} {word}{' ' + scope if scope else ''}{trend} ({detail}).")
        else:
            detail = ", ".join(f"{g.column}: {unit(g.mean_residual)}" for g in biased)
            sentences.append(f"In the {where} {subject} misses with opposite signs in different columns ({detail}).")
    structured = [r for r in runs if r.p_value < 0.05]
    if structured:
        sentences.append(
            "The runout residuals come in long runs of one sign (runs test p < 0.05) in "
            + ", ".join(r.column for r in structured)
            + ": a systematic, not random, misfit."
        )
    if len(sentences) == 1 and p_value < 0.01:
        sentences.append("No single phase or deposit region stands out: the misfit is spread over the curve.")
    return " ".join(sentences)
