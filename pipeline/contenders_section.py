"""The calibrated section's judgement of a model beyond its one curve (pipeline/calibrated_section.py
calls these): its fitted parameter against the physically plausible range, its predictions across a
against the scaling laws, and the diagnosis' contenders side by side with the column that would
decide between them."""

from __future__ import annotations

import math
from dataclasses import replace

from calibration.contenders import ContenderChoice
from calibration.decision import DecisionRule
from calibration.mechanisms import get_mechanisms
from calibration.scaling_laws import QUASI_2D_SOURCE, ScalingCheck


def plausibility_lines(parameters: dict[str, float], plausible: list[dict] | None = None) -> list[str]:
    """Each fitted mechanism parameter of {name: value} against its physically plausible range, in
    words: `plausible` ([{parameter, range, source}], calibrated.json's, for the column's material)
    where given, else the built-in one (calibration.mechanisms); none for the base model's friction
    and restitution."""
    by_parameter = {m.parameter: m for m in get_mechanisms()}
    for stated in plausible or []:
        by_parameter[stated["parameter"]] = replace(
            by_parameter[stated["parameter"]], plausible=tuple(stated["range"]), plausible_source=stated["source"]
        )
    said = [by_parameter[name].plausibility(value) for name, value in parameters.items() if name in by_parameter]
    return [f"**Plausibility.** {'; '.join(said)}.", ""] if said else []


def scaling_sentence(check: ScalingCheck) -> str:
    """How far the predictions across a lie from the quasi-2D channel law, in words."""
    if check.worst_a is None:
        return "**Scaling check.** No prediction ran, so none is held against the experimental scaling."
    worst = check.runout_fraction()[check.aspect_ratios.index(check.worst_a)]
    return (
        f"**Scaling check** against the dry-sand law of {QUASI_2D_SOURCE}: the "
        f"predicted final runout is off by a factor of {math.exp(check.runout_error):.2g} on average (RMS of "
        f"ln(predicted / law) {check.runout_error:.2f}), worst at a = {check.worst_a:g} ({worst:.2f} of the law); "
        f"the deposit height by a factor of {math.exp(check.height_error):.2g}. Where the model misses the law "
        "by a factor of 2 or more it will not predict those columns of the material: its parameters are "
        "effective values of the measured curve."
    )


def contenders_lines(choice: ContenderChoice) -> list[str]:
    """Markdown: every contender side by side (fit, the law per a, plausibility) and the choice."""
    a = choice.contenders[0].scaling.aspect_ratios
    per_a = " | ".join(f"a = {x:g}" for x in a)
    shifts = [c.grain_shift for c in choice.contenders if c.grain_shift is not None]
    moved = f"move {shifts[0].size_scales[0]:g} to {shifts[0].size_scales[1]:g}: MSE, chi^2" if shifts else "move"
    head = f"| model | parameters | DEM BIC | {per_a} | law chi^2 | {moved} | combined | plausible |"
    lines = [
        f"**The contenders, judged by what they predict.** Each model the diagnosis scored in the DEM, at its "
        f"fit, {pairs_clause(choice)}predicted across a on {len(choice.seeds)} packings; per a its mean final L* "
        f"over the {QUASI_2D_SOURCE} law (1 = on the law). The law enters as pseudo-data with tolerance "
        f"{choice.law_log_std:g} in ln L*. {move_sentence(shifts)}combined = BIC + law chi^2 + move chi^2 "
        f"({choice.seconds:.0f} s of DEM).",
        "",
        head,
        "|" + " --- |" * (7 + len(a)),
    ]
    for c in choice.contenders:
        fractions = " | ".join("failed" if f is None else f"{f:.2f}" for f in c.scaling.runout_fraction())
        parameters = ", ".join(f"{k} {v:.3g}" for k, v in c.parameters.items())
        plausible = "-" if c.model == "base" else ("yes" if c.physical else "no: effective")
        if c.switched_off:
            plausible += f"; fitted with {', '.join(c.switched_off)} off: not a pair"
        mark = f"**{c.model}**" if c.model == choice.chosen else c.model
        chi2 = f"{c.law_chi2:.1f}" if math.isfinite(c.law_chi2) else "-"
        shift = c.grain_shift
        move = "-" if shift is None or shift.chi2 is None else f"{shift.shift_mse:.3g}, {shift.chi2:.1f}"
        lines.append(
            f"| {mark} | {parameters} | {c.bic:.1f} | {fractions} | {chi2} | {move} | {c.combined:.1f} | {plausible} |"
        )
    lines += ["", choice.why, ""]
    if choice.deciding is not None:
        lines += [deciding_sentence(choice), ""]
    return lines


def move_sentence(shifts: list) -> str:
    """How each candidate's move with the grain size was measured, in words ("" where it was not)."""
    if not shifts:
        return ""
    coarse, fine = shifts[0].size_scales
    return (
        f"Each candidate's curve on the measured column moves when the grains get finer: its fit run at "
        f"size_scale {coarse:g} and {fine:g} on the same {len(shifts[0].seeds)} packings, the squared move of "
        "the mean curve less the packings' own scatter, as MSE and in units of the data's noise (chi^2): "
        "what the answer will not carry to another resolution. "
    )


def pairs_clause(choice: ContenderChoice) -> str:
    """How the pairs among the contenders were fitted, in words ("" without pairs)."""
    fits = [(c.model, c.pair_fit) for c in choice.contenders if c.pair_fit is not None]
    if not fits:
        return ""
    said = "; ".join(
        f"{model} from {fit.start}'s fit, runout MSE {fit.start_mse:.3g} to {fit.fit_mse:.3g} on packings of its "
        f"own, {fit.dem_runs} DEM runs, {fit.seconds:.0f} s"
        for model, fit in fits
    )
    return (
        f"and each pair of mechanisms fitted in the DEM from its better member's fit and scored by a BIC on the "
        f"diagnosis' packings and noise; a pair whose fit leaves one mechanism off is its other member at "
        f"another point and is not chosen ({said}), "
    )


def deciding_sentence(choice: ContenderChoice) -> str:
    """The column to measure next, in words: where the two best contenders' predictions part most."""
    d = choice.deciding
    first, second = (choice.contender(m) for m in d.models)
    margin = DecisionRule().min_delta_bic_vs_runner_up
    gap = second.combined - first.combined
    told = (
        f"Their combined scores differ by {gap:.1f}, within the margin of {margin:g}: the data do not decide "
        "between them. "
        if gap < margin
        else f"Their combined scores differ by {gap:.1f} (margin {margin:g}). "
    )
    apart = (
        f", {d.separation:.1f} standard errors of the difference apart (one packing's scatter {d.scatter:.2g})"
        if d.separation is not None
        else " (one packing each: no scatter to weigh the difference against)"
    )
    return (
        f"**The experiment that would decide.** {told}A column of a = {d.aspect_ratio:g} at L_i = {d.L_i:g} m "
        f"is where {d.models[0]} and {d.models[1]} part most: final L* {d.runout[0]:.3g} against "
        f"{d.runout[1]:.3g}{apart}. Measuring it tells them apart."
    )
