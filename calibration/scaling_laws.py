"""The experimental scaling of a dry granular column's final deposit with its aspect ratio a = H_i / L_i,
and how far a model's predictions across a lie from it.

A calibrated model fits one measured curve; these laws say what the same dry material does at other
a, so a model that misses them by a factor at other a has fitted the curve with the wrong mechanism.
Runout is L* = (L_f - L_i) / L_i, deposit height H_f / L_i.

- Quasi-2D channel, dry sand and other grains (Lube, Huppert, Sparks & Freundt 2005, Phys. Rev. E 72,
  041301): L* ~ 1.2 a for small a, 1.9 a^(2/3) for large a (crossover near a = 2-3); H_f = H_i (the
  top of the column untouched) for a below ~1.15, H_f / L_i ~ a^(2/5) above. The height law's
  coefficients are quoted from the paper's abstract as cited in the literature, not checked against
  its figures here; the runout law is the one the measured columns of this project lie on.
- True-2D discs or rods (arXiv:1512.05180): L* ~ 3.25 a^0.96 for a <= 1.5, 3.80 a^0.73 above, about
  twice the channel's: a 2D disc model left to itself behaves like these, not like sand.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

QUASI_2D_SOURCE = "Lube et al. (2005), quasi-2D channel"
DISC_2D_SOURCE = "true-2D discs (arXiv:1512.05180)"
RUNOUT_CROSSOVER = 2.8  # a at which the channel law switches from 1.2 a to 1.9 a^(2/3)
HEIGHT_CROSSOVER = 1.15  # a below which the column's top stays where it was


def quasi_2d_runout(aspect_ratio: float) -> float:
    """Final runout L* (-) of a dry column in a quasi-2D channel (Lube et al. 2005)."""
    a = aspect_ratio
    return 1.2 * a if a < RUNOUT_CROSSOVER else 1.9 * a ** (2.0 / 3.0)


def disc_2d_runout(aspect_ratio: float) -> float:
    """Final runout L* (-) of a true-2D column of discs (arXiv:1512.05180)."""
    a = aspect_ratio
    return 3.25 * a**0.96 if a <= 1.5 else 3.80 * a**0.73


def quasi_2d_height(aspect_ratio: float) -> float:
    """Final deposit height H_f / L_i (-) of a dry column in a quasi-2D channel (Lube et al. 2005)."""
    a = aspect_ratio
    return a if a < HEIGHT_CROSSOVER else a**0.4


def _log_ratio(value: float | None, law: float) -> float | None:
    """ln(value / law); None for a failed run, -inf-free: a non-positive value counts as a hundredth of the law."""
    if value is None or not math.isfinite(value):
        return None
    return math.log(max(value, 0.01 * law) / law)


def _rms(values: Sequence[float | None]) -> float:
    finite = [v for v in values if v is not None]
    return math.sqrt(sum(v * v for v in finite) / len(finite)) if finite else math.nan


@dataclass(frozen=True)
class ScalingCheck:
    """A model's final runout and deposit height per aspect ratio [A] against the quasi-2D channel
    law, and the true-2D disc law beside it. *_log_ratio [A] = ln(predicted / law), None where the run
    failed; runout_error and height_error = the RMS of those over the a that ran (0: on the law,
    ln 2 = 0.69: a factor of 2 off on average); worst_a: the a of the largest runout miss."""

    aspect_ratios: list[float]
    final_runout: list[float | None]
    runout_law: list[float]
    disc_law: list[float]
    runout_log_ratio: list[float | None]
    height_over_L_i: list[float | None]
    height_law: list[float]
    height_log_ratio: list[float | None]
    runout_error: float
    height_error: float
    worst_a: float | None

    def to_dict(self) -> dict:
        return asdict(self)

    def runout_fraction(self) -> list[float | None]:
        """Predicted over law runout per a: 1 on the law, 0.05 for a column that hardly moves."""
        return [None if r is None else math.exp(r) for r in self.runout_log_ratio]


def check_scaling(
    aspect_ratios: Sequence[float], final_runout: Sequence[float | None], height_over_L_i: Sequence[float | None]
) -> ScalingCheck:
    """Score predictions [A] (final L*, H_f / L_i; None where a run failed) at aspect_ratios [A]
    against the quasi-2D channel law."""
    if not (len(aspect_ratios) == len(final_runout) == len(height_over_L_i)):
        raise ValueError(
            f"scaling check: {len(aspect_ratios)} aspect ratios, {len(final_runout)} runouts, "
            f"{len(height_over_L_i)} heights; give one of each per aspect ratio"
        )
    a = [float(x) for x in aspect_ratios]
    runout_law = [quasi_2d_runout(x) for x in a]
    height_law = [quasi_2d_height(x) for x in a]
    runout_ratio = [_log_ratio(v, law) for v, law in zip(final_runout, runout_law)]
    height_ratio = [_log_ratio(v, law) for v, law in zip(height_over_L_i, height_law)]
    missed = [(abs(r), x) for r, x in zip(runout_ratio, a) if r is not None]
    return ScalingCheck(
        aspect_ratios=a,
        final_runout=list(final_runout),
        runout_law=runout_law,
        disc_law=[disc_2d_runout(x) for x in a],
        runout_log_ratio=runout_ratio,
        height_over_L_i=list(height_over_L_i),
        height_law=height_law,
        height_log_ratio=height_ratio,
        runout_error=_rms(runout_ratio),
        height_error=_rms(height_ratio),
        worst_a=max(missed)[1] if missed else None,
    )
