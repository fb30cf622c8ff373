"""What mu accuracy can ANY calibration reach from a runout curve of this column? DEM alone; prints JSON.

On the inverse-design dataset's column (config datasets.<dataset>: quartz a = 6, L_i = 0.02 m,
coarse-grained 5x) the builtin DEM is run on several packing seeds at a few (mu, e) points. From
these runs:
  * packing scatter: the std of L*(t/t* = 0.5 .. 3.5) between packings (pooled over the points) and
    its correlation across t (one packing shifts the whole curve);
  * sensitivity: d(mean L*)/dmu and d(mean L*)/de between neighbouring levels (with standard errors);
  * the best possible accuracy (Cramer-Rao bound of the linearised problem, both parameters fitted):
    a target curve = mean of k packings + measurement noise sigma_m (independent per point) has
    covariance C_k = S / k + sigma_m^2 I (S: packing covariance). A calibration against a model of
    the MEAN response then has cov(mu, e) >= (J^T C_k^-1 J)^-1, J = [dL*/dmu, dL*/de]. A model
    that itself runs ONE packing (a single DEM run, a GNS rolled out from one packing) adds S again.
Verdict per mu level: the std of mu and whether "mu within 0.03" holds at 95% (1.96 std <= 0.03).
As a check without linearisation, an empirical leave-packings-out recovery along the friction line
(e known, the "model" being the mean curves of the other packings): the mu errors it makes.

    python benchmarks/recovery_feasibility.py [--seeds 4] [--out /tmp/inv_work/feasibility] [--curves OLD.json]

Cost: (5 friction + 2 restitution levels) x seeds runs of ~10 CPU-s each (~5 CPU-min for 4 seeds).
"""

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calibration.uncertainty import Z95  # noqa: E402
from dem.collapse import simulate_collapse  # noqa: E402
from dem.grid import case_from_row, sample_dataset  # noqa: E402
from dem.runout import RunoutMethod, runout_at  # noqa: E402
from dem.trajectory import write_trajectory  # noqa: E402
from pipeline.config import validate_config  # noqa: E402

T_POINTS = np.array([0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5])  # the measured curve's t/t*
FRICTION_LEVELS = (0.3, 0.45, 0.6, 0.75, 0.9)
RESTITUTION_LEVELS = (0.3, 0.6, 0.9)
MIDDLE = (0.6, 0.6)  # where the restitution line crosses the friction line
SEED_BASE = 30_000  # packing seeds far from the datasets' and recovery's
MEASUREMENT_NOISE = 0.05  # L*, per point
K_PACKINGS = (1, 2, 4, 8, 16)
MU_TOLERANCE = 0.03
RUNOUT = RunoutMethod()  # the project's default runout method (config key runout)


def template_case(config_path: Path, dataset: str):
    """The dataset's first case (its column, grain scale, frame interval, contact constants)."""
    config = validate_config(yaml.safe_load(config_path.read_text()), ROOT / "workflow/schemas/config.schema.yaml")
    return case_from_row(sample_dataset(dataset, config["datasets"][dataset])[0])


def runs_at(case, friction, restitution, seeds, save=None) -> np.ndarray:
    """[S, K] L* at T_POINTS of one DEM run per packing seed (each settled with its own contact law).
    save: folder to write each trajectory to (e.g. a small GNS dataset for timing), or None."""
    curves = []
    for seed in seeds:
        t0 = time.perf_counter()
        name = f"feasibility_{friction:g}_{restitution:g}_{seed}"
        trajectory = simulate_collapse(
            case.replace(friction=friction, restitution=restitution, seed=int(seed), name=name)
        )
        if save is not None:
            write_trajectory(save / f"{name}.h5", trajectory)
        curves.append(runout_at(trajectory, T_POINTS, RUNOUT))
        print(
            f"mu {friction:.2f} e {restitution:.2f} seed {seed}: L*(3.5) = {curves[-1][-1]:.3f} "
            f"({time.perf_counter() - t0:.1f} s)",
            file=sys.stderr,
            flush=True,
        )
    return np.array(curves)


def slopes(levels, curves) -> list[dict]:
    """d(mean L*)/d(level) [K] between neighbouring levels, with its standard error (seed scatter)."""
    out = []
    for (a, ca), (b, cb) in zip(zip(levels, curves), zip(levels[1:], curves[1:])):
        slope = (cb.mean(0) - ca.mean(0)) / (b - a)
        error = np.sqrt(cb.var(0, ddof=1) / len(cb) + ca.var(0, ddof=1) / len(ca)) / (b - a)
        out.append({"between": [a, b], "at": 0.5 * (a + b), "slope": slope.tolist(), "stderr": error.tolist()})
    return out


def mu_std(jacobian, covariance) -> float:
    """std of mu from the Fisher information J^T C^-1 J of the fit of jacobian's columns (mu first)."""
    fisher = jacobian.T @ np.linalg.solve(covariance, jacobian)
    return float(np.sqrt(np.linalg.inv(fisher)[0, 0]))


def empirical_recovery(curves, k: int, seed: int = 0) -> list[dict]:
    """Leave-packings-out recovery of mu along the friction line (e known), with no surrogate at all.

    For each friction level and each choice of k of its packings: the target is their mean L* plus
    measurement noise; the "model" is the mean curve of the OTHER packings at every level,
    interpolated linearly in mu; mu is the grid minimiser of the runout MSE. Returns per level the
    errors |mu_hat - mu| over the choices: what a perfect surrogate of the mean could do at best.
    """
    from itertools import combinations

    rng = np.random.default_rng(seed)
    levels = np.array(FRICTION_LEVELS)
    grid = np.linspace(levels[0], levels[-1], 601)
    n_seeds = len(curves[0])
    rows = []
    for i, level in enumerate(levels):
        errors = []
        for chosen in combinations(range(n_seeds), k):
            rest = [j for j in range(n_seeds) if j not in chosen]
            if not rest:
                continue
            target = curves[i][list(chosen)].mean(0) + rng.normal(0.0, MEASUREMENT_NOISE, len(T_POINTS))
            means = np.array([c[rest].mean(0) for c in curves])  # [levels, K]
            model = np.array([np.interp(grid, levels, means[:, t]) for t in range(len(T_POINTS))]).T
            mu_hat = grid[np.argmin(np.mean((model - target) ** 2, axis=1))]
            errors.append(abs(mu_hat - level))
        rows.append(
            {
                "mu": float(level),
                "k": k,
                "errors": np.round(errors, 4).tolist(),
                "mean_abs_error": float(np.mean(errors)),
                "within_0.03": f"{sum(e <= MU_TOLERANCE for e in errors)}/{len(errors)}",
            }
        )
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "config/config.yaml")
    parser.add_argument("--dataset", default="quartz_multiple")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--out", type=Path, default=Path("/tmp/inv_work/feasibility"))
    parser.add_argument("--save-trajectories", type=Path, default=None, help="folder for the DEM runs (HDF5)")
    parser.add_argument(
        "--curves",
        type=Path,
        default=None,
        help="a JSON this script wrote: analyse its runout curves again instead of running the DEM",
    )
    args = parser.parse_args()
    if args.save_trajectories:
        args.save_trajectories.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    case = template_case(args.config, args.dataset)
    seeds = SEED_BASE + np.arange(args.seeds)
    save = args.save_trajectories
    if args.curves:
        saved = json.loads(args.curves.read_text())
        seeds = np.array(saved["seeds"])
        friction_curves = [np.array(saved["curves"]["friction"][f"{mu:g}"]) for mu in FRICTION_LEVELS]
        restitution_curves = [np.array(saved["curves"]["restitution"][f"{e:g}"]) for e in RESTITUTION_LEVELS]
    else:
        friction_curves = [runs_at(case, mu, MIDDLE[1], seeds, save) for mu in FRICTION_LEVELS]
        middle = friction_curves[FRICTION_LEVELS.index(MIDDLE[0])]
        restitution_curves = [
            middle if e == MIDDLE[1] else runs_at(case, MIDDLE[0], e, seeds, save) for e in RESTITUTION_LEVELS
        ]
    groups = friction_curves + [c for e, c in zip(RESTITUTION_LEVELS, restitution_curves) if e != MIDDLE[1]]

    # packing covariance [K, K], pooled over the points (each point's own mean removed)
    residuals = np.concatenate([c - c.mean(0) for c in groups])
    dof = len(residuals) - len(groups)
    packing_cov = residuals.T @ residuals / dof
    packing_std = np.sqrt(np.diag(packing_cov))
    correlation = packing_cov / np.outer(packing_std, packing_std)
    per_point_std = {
        f"{mu:g},{MIDDLE[1]:g}": c.std(0, ddof=1).tolist() for mu, c in zip(FRICTION_LEVELS, friction_curves)
    }

    friction_slopes = slopes(FRICTION_LEVELS, friction_curves)
    restitution_slopes = slopes(RESTITUTION_LEVELS, restitution_curves)
    # restitution sensitivity: one value per t (the mean slope over the e line), used at every mu
    de = np.mean([s["slope"] for s in restitution_slopes], axis=0)
    accuracy = []
    for s in friction_slopes:
        jacobian = np.column_stack([s["slope"], de])
        row = {"mu": s["at"]}
        for k in K_PACKINGS:
            target = packing_cov / k + MEASUREMENT_NOISE**2 * np.eye(len(T_POINTS))
            mean_model = mu_std(jacobian, target)
            one_packing_model = mu_std(jacobian, target + packing_cov)
            e_known = mu_std(jacobian[:, :1], target)
            row[f"k={k}"] = {
                "mu_std_mean_model": mean_model,
                "mu_std_single_packing_model": one_packing_model,
                "mu_std_e_known": e_known,
                "within_0.03_at_95%": bool(Z95 * mean_model <= MU_TOLERANCE),
                "within_0.03_at_95%_e_known": bool(Z95 * e_known <= MU_TOLERANCE),
            }
        # smallest k that reaches mu within 0.03 at 95% with a model of the mean response
        reach = [k for k in K_PACKINGS if row[f"k={k}"]["within_0.03_at_95%"]]
        row["min_k_for_0.03"] = reach[0] if reach else None
        accuracy.append(row)

    summary = {
        "dataset": args.dataset,
        "n_particles": case.n_particles,
        "size_scale": case.size_scale,
        "t_over_tstar": T_POINTS.tolist(),
        "seeds": seeds.tolist(),
        "measurement_noise": MEASUREMENT_NOISE,
        "packing_std": packing_std.tolist(),
        "packing_std_dof": dof,
        "packing_correlation": correlation.round(3).tolist(),
        "packing_std_per_point": per_point_std,
        "curves": {
            "friction": {f"{mu:g}": c.tolist() for mu, c in zip(FRICTION_LEVELS, friction_curves)},
            "restitution": {f"{e:g}": c.tolist() for e, c in zip(RESTITUTION_LEVELS, restitution_curves)},
        },
        "mean_curves": {
            "friction": {f"{mu:g}": c.mean(0).tolist() for mu, c in zip(FRICTION_LEVELS, friction_curves)},
            "restitution": {f"{e:g}": c.mean(0).tolist() for e, c in zip(RESTITUTION_LEVELS, restitution_curves)},
        },
        "dL_dmu": friction_slopes,
        "dL_de": restitution_slopes,
        "dL_de_mean": de.tolist(),
        "mu_accuracy": accuracy,
        "empirical_recovery_e_known": [
            r for k in (1, 2) if k < len(seeds) for r in empirical_recovery(friction_curves, k)
        ],
        "curves_from": str(args.curves) if args.curves else "DEM runs of this call",
        "cpu_s": time.process_time(),
        "wall_s": time.perf_counter() - start,
        "machine": platform.processor() or platform.machine(),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    plot(summary, friction_curves, restitution_curves, args.out / "recovery_feasibility.png")
    from dem.atomic import write_text

    write_text(args.out / "recovery_feasibility.json", json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary, indent=1))


def plot(summary, friction_curves, restitution_curves, path):
    """Runout curves of every packing (thin) and their means (thick) along mu and e; the mu std
    reachable against k, per mu level."""
    from dem.plots import plt, save_figure

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for ax, levels, curves, name in (
        (axes[0], FRICTION_LEVELS, friction_curves, "mu"),
        (axes[1], RESTITUTION_LEVELS, restitution_curves, "e"),
    ):
        for j, (level, c) in enumerate(zip(levels, curves)):
            colour = plt.get_cmap("viridis")(j / max(len(levels) - 1, 1))
            ax.plot(T_POINTS, c.T, "-", color=colour, lw=0.6, alpha=0.6)
            ax.plot(T_POINTS, c.mean(0), "-o", color=colour, lw=2, ms=3, label=f"{name} = {level:g}")
        other = f"e = {MIDDLE[1]:g}" if name == "mu" else f"mu = {MIDDLE[0]:g}"
        ax.set(xlabel="t/t*", ylabel="L*", title=f"{len(curves[0])} packings per point ({other})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    ax = axes[2]
    for row in summary["mu_accuracy"]:
        ks = K_PACKINGS
        (line,) = ax.plot(
            ks, [row[f"k={k}"]["mu_std_mean_model"] * Z95 for k in ks], "-o", ms=3, label=f"mu ~ {row['mu']:.3g}"
        )
        ax.plot(ks, [row[f"k={k}"]["mu_std_e_known"] * Z95 for k in ks], "--", color=line.get_color(), lw=0.8)
    ax.axhline(MU_TOLERANCE, color="r", ls="--", lw=1, label=f"{MU_TOLERANCE:g}")
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="packings averaged in the target (k)",
        ylabel="95% half-width of mu",
        title=f"best reachable mu (noise {MEASUREMENT_NOISE:g} L*; dashed: e known)",
    )
    ax.set_xticks(K_PACKINGS, [str(k) for k in K_PACKINGS])
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.suptitle(
        f"{summary['dataset']}: {summary['n_particles']} grains; packing std of L* "
        + " ".join(f"{s:.2f}" for s in summary["packing_std"]),
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    main()
