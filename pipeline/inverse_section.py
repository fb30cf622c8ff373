"""The report's section of the inverse design (workflow rule inverse_section): results/report/inverse.md
from every measured column's inverse.json (pipeline/inverse_design.py writes those) and comparison
table of the calibration routes (pipeline/inverse.py's run_comparison), with the figures beside
them, then the parameter recovery of each GNS on synthetic targets.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from calibration.compare import Route, markdown_table, read_table
from calibration.inverse_result import read_result
from calibration.measured import load_column
from calibration.measured_column import MeasuredColumn
from dem.atomic import StrPath, write_text


def section(
    name: str,
    measured: MeasuredColumn,
    routes: list[Route],
    inverse: dict,
    figures: dict,
    section_path: StrPath,
    recovery: dict | None = None,
) -> str:
    """Markdown report section of one measured column (links relative to section_path)."""
    here = Path(section_path).parent
    rel = {k: Path(os.path.relpath(v, here)).as_posix() for k, v in figures.items()}
    post = inverse["posterior"]
    lines = [f"### {name}: {measured.material}, a = {measured.aspect_ratio:g}, L_i = {measured.L_i:g} m", ""]
    geometry = inverse["geometry"]
    if geometry["distance"] > 0.05:
        lines += [
            f"**Warning:** the GNS was not trained on this column: the nearest training column "
            f"(a = {geometry['nearest'][0]:g}, L_i = {geometry['nearest'][1]:g} m) is "
            f"{geometry['distance']:.0%} away.",
            "",
        ]
    lines += [
        f"GNS inverse design: {len(inverse['starts'])} L-BFGS-B starts in lockstep ({inverse['gradient']} "
        f"gradients through the checkpointed rollout), {inverse['n_batches']} batched rollouts, "
        f"online time {inverse['seconds']['online']:.1f} s. Optimum (GNS objective "
        f"{inverse['best_value']:.3f}):",
        "",
        "| parameter | optimum | std | 95% interval | identifiable |",
        "|---|---|---|---|---|",
    ]
    for p in post["parameters"]:
        lines.append(
            f"| {p['name']} | {p['value']:.3f} | {p['std']:.3f} | [{p['low']:.3f}, {p['high']:.3f}] | "
            f"{'yes' if p['identifiable'] else 'no: ' + p['why']} |"
        )
    lines += [
        "",
        f"Posterior correlation of the two parameters: {post['correlation'][0][1]:.2f}; noise: "
        f"{post['sigma_source']} (std {np.mean(post['sigma']):.3g} in L*).{likelihood_sentence(post)}",
        "",
        "| start (mu, e) | end (mu, e) | GNS objective | iterations | rollouts | L-BFGS-B |",
        "|---|---|---|---|---|---|",
    ]
    for s in inverse["starts"]:
        lines.append(
            f"| {s['start'][0]:.3f}, {s['start'][1]:.3f} | {s['params'][0]:.3f}, {s['params'][1]:.3f} | "
            f"{s['iterates'][0]['value']:.4g} -> {s['value']:.4g} | {s['n_iterations']} | "
            f"{s['n_evaluations']} | {s['message']} |"
        )
    rough = inverse.get("roughness")
    if rough:
        listed = lambda values: ", ".join("failed" if v is None else f"{v:.3g}" for v in values)  # noqa: E731
        lines += [
            "",
            f"Roughness of the GNS objective: within {rough['radius']:g} of the optimum it spans "
            f"{rough['spread']:.3g} ({listed(rough['values'])} around "
            f"{rough['optimum_value']:.3g}); the posterior's steps of {rough['jacobian_step']:g} give "
            f"{listed(rough['jacobian_step_values'])}. Where the spread is comparable, "
            "the rollout is chaotic in (mu, e) at that scale (as the DEM is between packings): local "
            "gradients, exact or finite-difference, describe that noise rather than the trend.",
        ]
    lines += [
        "",
        "Validated against the measured runout (DEM runs at each optimum; the paper: start 0.66, "
        "GNS 0.10, DoE 0.17 for quartz):",
        "",
        markdown_table(routes),
        "",
    ]
    for key, caption in (
        ("paths", "optimisation paths over the objective landscape (Fig. 2)"),
        ("deposits", "GNS deposits during the optimisation (Fig. 9)"),
        ("runout", "DEM runout at each optimum against the measurement (Fig. 10)"),
        ("comparison", "validated objective against DEM runs and wall time (Table 5)"),
        ("bayesopt", "Bayesian optimisation on DEM runs"),
    ):
        if key in rel:
            lines += [f"![{caption}]({rel[key]})", ""]
    return "\n".join(lines)


def report_section(
    names: Sequence[str],
    measured_paths: Sequence[StrPath],
    inverse_paths: Sequence[StrPath],
    table_paths: Sequence[StrPath],
    figures: dict,
    section_path: StrPath,
    recovery_paths: Sequence[StrPath] = (),
    recovery_figures: Sequence[StrPath] = (),
) -> str:
    """The inverse-design report section: per measured column the optimum with its uncertainty, the
    comparison table and figures; then the parameter recovery of each GNS on synthetic targets.

    figures: {name: {"paths", "deposits", "runout", "comparison", "bayesopt": path}}.
    """
    parts = [
        "Calibration of (mu, e) through the trained GNS (L-BFGS-B within bounds, as Jiang et al. 2024), "
        "checked by DEM runs at the optimum and compared with the DoE and with Bayesian optimisation "
        "directly on DEM runs. Wall times are sums of job times (one core each) from the benchmark files.",
        "",
    ]
    for k, name in enumerate(names):
        parts.append(
            section(
                name,
                load_column(measured_paths[k]),
                read_table(table_paths[k]),
                read_result(inverse_paths[k]),
                figures[name],
                section_path,
            )
        )
    here = Path(section_path).parent
    for path, figure in zip(recovery_paths, recovery_figures):
        summary = json.loads(Path(path).read_text())
        packings = summary.get("packings", 1)
        scatter = summary.get("packing_std")
        model_error = summary["model_error_std"]
        parts += [
            f"### Parameter recovery on synthetic DEM targets ({summary['dataset']})",
            "",
            f"{summary['n_cases']} targets of the dataset's column with known (mu, e) not in its training set, "
            f"each the mean runout of {packings} DEM packing(s) (as a lab averages repeated tests) at t/t* = "
            f"{', '.join(f'{t:g}' for t in summary['t_over_tstar'])} plus Gaussian noise "
            f"(std {summary['noise_std']:g}). "
            + (
                f"The runout scatters between packings by {min(scatter):.2g}-{max(scatter):.2g} L* (pooled, "
                f"{summary['packing_dof']} dof); the posterior's noise holds the noise, that scatter / "
                f"sqrt({packings}) on the target side and the scatter of the one packing the GNS rolls out"
                if scatter
                else "The posterior's noise holds the noise"
            )
            + (
                ""
                if model_error is None
                else f", and the GNS's own runout error on its test split at each point, "
                f"{min(model_error):.2g}-{max(model_error):.2g}"
            )
            + f". mu within {summary['mu_tolerance']:g}: "
            f"**{summary['mu_within']} of {summary['n_cases']}**; truth inside both 95% intervals: "
            f"**{summary['truth_inside_95']} of {summary['n_cases']}** (target: all, and 4 of 5).",
            "",
            "| target | true mu, e | recovered mu, e | 95% interval mu | 95% interval e | identifiable | mu error |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in summary["cases"]:
            parts.append(
                f"| {r['target']} | {r['truth'][0]:.3f}, {r['truth'][1]:.3f} | {r['estimate'][0]:.3f}, "
                f"{r['estimate'][1]:.3f} | [{r['interval'][0][0]:.3f}, {r['interval'][0][1]:.3f}] | "
                f"[{r['interval'][1][0]:.3f}, {r['interval'][1][1]:.3f}] | "
                f"{', '.join('yes' if i else 'no' for i in r['identifiable'])} | {r['mu_error']:.3f} |"
            )
        parts += ["", f"![parameter recovery]({Path(os.path.relpath(figure, here)).as_posix()})", ""]
    return "\n".join(parts)


def write_section(
    names: Sequence[str],
    measured_paths: Sequence[StrPath],
    inverse_paths: Sequence[StrPath],
    table_paths: Sequence[StrPath],
    section_path: StrPath,
    recovery_paths: Sequence[StrPath] = (),
    recovery_figures: Sequence[StrPath] = (),
    *,
    bayesopt: bool = False,
) -> str:
    """Write results/report/inverse.md (atomically) and return its text: report_section with each
    column's figures beside its inverse.json (paths, deposits, runout, comparison.png, and
    bayesopt.png when the BO arm ran)."""
    figures = {}
    for name, result in zip(names, inverse_paths):
        folder = Path(result).parent
        figures[name] = {key: folder / f"{key}.png" for key in ("paths", "deposits", "runout", "comparison")}
        if bayesopt:
            figures[name]["bayesopt"] = folder / "bayesopt.png"
    text = report_section(
        names, measured_paths, inverse_paths, table_paths, figures, section_path, recovery_paths, recovery_figures
    )
    write_text(section_path, text)
    return text


def likelihood_sentence(post: dict) -> str:
    """How far the GNS's own chi^2 along each interval widened the Laplace posterior (calibration.
    uncertainty.likelihood_checked); "" for a posterior not checked."""
    check = post.get("likelihood_check")
    if not check:
        return ""
    names = [p["name"] for p in post["parameters"]]
    scales = ", ".join(f"{n} x {c:.2g}" for n, c in zip(names, check["scale"]))
    return (
        f" Held to the GNS's own chi^2 along each interval ({sum(len(e['rise']) for e in check['ends'])} "
        f"rollouts): std {scales} (x 1: the Laplace interval stood; more: the rollout's slope at the "
        "optimum overstated its trend, or its chi^2 came back down beyond a bump)."
    )
