"""The verdict of the diagnosis: whether a candidate mechanism is named the cause.

`decide`, `DecisionRule`: the cause is the best candidate only when, in DEM runs, it beats the base
model and the runner-up by stated BIC margins, predicts the held-out data better than the base
model by a stated gain and no worse than the runner-up (beyond the chance scatter of a held-out
chi^2), the emulators rank it first too, and the data raised no warning; otherwise "none", with the
checks that failed. `unsettled` says when such a "none" is worth another round of DEM evidence.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

from calibration.dem_scoring import DEMScore


@dataclass(frozen=True)
class DecisionRule:
    """When a cause is named. Margins on the BIC follow Kass & Raftery (1995): a difference of 10
    is "very strong" evidence, 6 "strong"."""

    misfit_p_value: float = 0.01  # the base model "misfits beyond the noise" below this p (reported)
    min_delta_bic_vs_base: float = 10.0  # BIC(base) - BIC(best) at least this
    min_delta_bic_vs_runner_up: float = 6.0
    min_heldout_gain: float = 0.25  # held-out chi^2 at least this fraction below the base model's
    # The held-out chi^2 of the best candidate may exceed the runner-up's by at most this many
    # standard deviations of a chi^2 over the n held-out values, sqrt(2 n): a smaller difference is
    # a tie, and a tie does not overturn the BIC margin (it would veto a decisive fit on a coin
    # flip). More than that, and the best fit in sample predicts worse out of sample: overfitting.
    heldout_tie_sd: float = 1.0

    def to_dict(self) -> dict:
        return asdict(self)


# -- the decision ----------------------------------------------------------------------------------------
def decide(
    dem: Mapping[str, DEMScore],
    rule: DecisionRule,
    data_warnings: Sequence[str],
    emulator_best: str | None = None,
    switched_on: Mapping[str, bool] | None = None,
) -> tuple[str, dict[str, bool], str]:
    """(cause, checks {name: bool}, verdict in words) from the DEM scores {model: DEMScore} (read:
    bic, heldout_chi2, n_heldout, p_value), which hold the base model and the candidates the
    emulator ranked highest. data_warnings: what reading the data warned of (any forbids a cause).

    The base model is each extension with its mechanism off, so "BIC beats base by 10" is a
    likelihood-ratio test of "off" (chi^2 drop >= 10 + ln n for one parameter; p < 1e-3 for
    n ~ 20). Whether the base model alone misfits beyond the noise is reported, not required: a
    mechanism can be needed even when the noise is large enough to hide it from a chi^2 test.
    emulator_best: the candidate the emulators rank first; the DEM must agree (where the two
    disagree, one of them is wrong about the optimum, and the evidence is not decisive).
    switched_on: {candidate: whether its fit switches its mechanism on} (calibration.diagnosis.
    mechanism_on); a candidate fitted with its mechanism off is the base model at another (mu, e),
    never a cause. None: not checked.
    """
    base = dem["base"]
    ranked = sorted((n for n in dem if n != "base"), key=lambda n: dem[n].bic)
    best = ranked[0]
    runner_up = ranked[1] if len(ranked) > 1 else None
    b, r = dem[best], dem[runner_up] if runner_up else None
    tie = rule.heldout_tie_sd * math.sqrt(2 * b.n_heldout)
    checks = {
        "data_without_warnings": not data_warnings,
        "bic_beats_base": base.bic - b.bic >= rule.min_delta_bic_vs_base,
        "bic_beats_runner_up": r is None or r.bic - b.bic >= rule.min_delta_bic_vs_runner_up,
        "heldout_beats_base": b.heldout_chi2 <= (1 - rule.min_heldout_gain) * base.heldout_chi2,
        "heldout_no_worse_than_runner_up": r is None or b.heldout_chi2 - r.heldout_chi2 <= tie,
        "emulator_agrees": emulator_best is None or emulator_best == best,
        "mechanism_on": switched_on is None or switched_on.get(best, True),
    }
    versus = f"runner-up {runner_up}: {base.bic - r.bic:.1f}" if r else "no runner-up"
    fits = "misfits beyond" if base.p_value < rule.misfit_p_value else "fits within"
    if all(checks.values()):
        verdict = (
            f"Cause: {best}. The calibrated base model {fits} the noise (p = {base.p_value:.2g}); "
            f"adding {best} lowers the BIC by {base.bic - b.bic:.1f} ({versus}) and the held-out "
            f"chi^2 from {base.heldout_chi2:.1f} to {b.heldout_chi2:.1f} (runner-up "
            f"{r.heldout_chi2 if r else float('nan'):.1f}), all in DEM runs."
        )
        return best, checks, verdict
    failed = [k for k, ok in checks.items() if not ok]
    if base.bic - b.bic < 0:
        why = f"no candidate improves on the calibrated base model, which {fits} the noise (p = {base.p_value:.2g})"
    else:
        why = (
            f"the best candidate, {best} (BIC {base.bic - b.bic:+.1f} vs base; {versus}), "
            f"is not decisive: {', '.join(failed)} failed"
        )
    return "none", checks, f"No cause named: {why}."


def unsettled(cause: str, checks: Mapping[str, bool]) -> bool:
    """Whether a verdict (`decide`'s cause and checks) is worth another DEM scoring round: "none",
    though a candidate beats the base model by the BIC margin in DEM runs and the data raised no
    warning. Such a candidate explains the data far beyond their noise, yet fails a margin that
    depends on how close its DEM runs lie to its optimum (held out, against the runner-up, the
    emulators' ranking); a round of refinement moves them closer. A "none" because no candidate
    beats the base model is settled: refining cannot create the evidence."""
    return cause == "none" and checks["bic_beats_base"] and checks["data_without_warnings"]
