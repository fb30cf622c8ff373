"""One GNS for the base model and the extended one? Trains it on both datasets and scores all three; prints JSON.

  python benchmarks/shared_gns.py --dag DIR [--out DIR/results/shared_gns] [--base quartz_multiple]
                                  [--model calibrated_quartz] [--held-out 12] [--steps N] [--threads 2]
                                  [--seed 0]

DIR: a finished default DAG. The default trains two GNSs on one column: the base model's (friction,
restitution; `--base`) and the extended model's (the diagnosis' mechanism added; `--model`), whose
box for the mechanism's parameter leaves out the value that switches it off. This trains a third on
the union of both datasets' cases, with the mechanism's parameter at its off value (0) in the base
cases, so the one box spans both models, at the extended model's settings (its checkpoint's). Then
every GNS rolls out held-out DEM runs that none of them saw: each dataset's test split and
`--held-out` new runs per model, drawn as a Latin hypercube of that model's box, each on a packing
of its own seed. A run's score is the rollout's runout MSE (L* read by the DAG's runout method).

Prints, per GNS and per model's held-out runs: their mean runout MSE with its standard error, and
the shared GNS's paired difference to the model's own GNS on the same runs; the training seconds of
each GNS. `--seed` other than 0 trains all three again with that seed (the DAG's are seed 0's), in
OUT/train and OUT/own_<dataset>: a second draw of the comparison. Writes OUT/summary.json and
OUT/shared_gns.png (every run's MSE, per GNS). Resumable: the held-out runs, the training
checkpoints and the rollouts already in OUT are kept.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

HELD_OUT_SEED = 7_000_000  # packing seeds of the held-out runs: none of the datasets' own


def held_out_runs(dag: Path, dataset: str, box: dict, n: int, out_dir: Path, seed: int) -> list[Path]:
    """`n` DEM runs of the case of `dataset`'s case_000 deck with its parameters drawn from `box`
    ({name: [low, high]}, a Latin hypercube), each on a packing of its own seed; [paths]."""
    from scipy.stats import qmc

    from dem.case import CollapseCase
    from dem.collapse import simulate_collapse
    from dem.trajectory import write_trajectory

    deck = json.loads((dag / "results/dem" / dataset / "decks/case_000.json").read_text())
    case = CollapseCase.from_dict(deck["case"])
    names = list(box)
    unit = qmc.LatinHypercube(d=len(names), seed=seed).random(n)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, u in enumerate(unit):
        path = out_dir / f"held_out_{i:03d}.h5"
        if not path.exists():
            values = {k: float(box[k][0] + x * (box[k][1] - box[k][0])) for k, x in zip(names, u)}
            run = case.replace(**values, seed=HELD_OUT_SEED + seed * 1000 + i, name=f"{dataset}/held_out_{i:03d}")
            start = time.perf_counter()
            write_trajectory(path, simulate_collapse(run))
            print(f"DEM {path.name} {values}: {time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)
        paths.append(path)
    return paths


def test_paths(dag: Path, metadata: dict) -> list[Path]:
    return [dag / p for p in metadata["splits"]["test"]]


def shared_metadata(dag: Path, base: dict, model: dict, out_path: Path) -> dict:
    """The union of both datasets' splits (absolute paths), over the extended model's parameters."""
    from gns.dataset import SPLITS, build_dataset

    if out_path.exists():
        return json.loads(out_path.read_text())
    splits = {s: [str(dag / p) for p in base["splits"][s] + model["splits"][s]] for s in SPLITS}
    return build_dataset(splits, out_path, name=f"{base['name']}+{model['name']}", parameters=dem_parameters(model))


def dem_parameters(metadata: dict) -> list[str]:
    """The DEM parameters a GNS of this dataset takes (as SimulatorConfig.parameter_names)."""
    from gns.simulator import NOT_PARAMETERS

    return [k for k in metadata["parameter_ranges"] if k not in NOT_PARAMETERS]


def score(model_path: Path, runs: list[Path], out_dir: Path, runout) -> list[float]:
    """Runout MSE of the GNS at `model_path` rolled out on each DEM run (rollouts kept in out_dir)."""
    from dem.trajectory import read_trajectory, write_trajectory
    from gns.evaluate import rollout_runout_mse
    from gns.rollout import rollout_trajectory
    from gns.simulator import load_simulator

    simulator = load_simulator(model_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    mses = []
    for run in runs:
        dem = read_trajectory(run)
        path = out_dir / f"{run.parent.parent.name}_{run.parent.name}_{run.stem}.h5"
        if path.exists():
            gns = read_trajectory(path)
        else:
            gns = rollout_trajectory(simulator, dem, on_invalid="flag")
            write_trajectory(path, gns)
        mses.append(rollout_runout_mse(dem, gns, runout) if gns.attrs["rollout_valid"] else float("nan"))
    return mses


def training_settings(model_path: Path, steps: int | None, seed: int) -> dict:
    """The settings a trained GNS was trained with (its checkpoint's), with `steps` and `seed` laid over."""
    import torch

    settings = dict(torch.load(model_path, map_location="cpu", weights_only=False)["settings"])
    if steps:
        settings["steps"] = steps
    settings["seed"] = seed
    return settings


def job_seconds(dag: Path, dataset: str) -> float | None:
    """The DAG's training job of `dataset`: its benchmark file's wall seconds (None: no such file)."""
    from pipeline.benchmarks import benchmark_seconds

    seconds, jobs = benchmark_seconds([dag / "results/benchmarks/gns/gns_train" / f"{dataset}.tsv"])
    return seconds if jobs else None


def summarise(mses: list[float]) -> dict:
    x = np.asarray(mses, dtype=float)
    ok = x[np.isfinite(x)]
    return {
        "n": int(len(x)),
        "failed": int(len(x) - len(ok)),
        "runout_mse_mean": float(ok.mean()),
        "runout_mse_se": float(ok.std(ddof=1) / np.sqrt(len(ok))),
        "runout_mse_median": float(np.median(ok)),
        "cases": [float(v) for v in x],
    }


def paired(shared: list[float], own: list[float]) -> dict:
    d = np.asarray(shared) - np.asarray(own)
    d = d[np.isfinite(d)]
    return {"mean": float(d.mean()), "se": float(d.std(ddof=1) / np.sqrt(len(d))), "n": int(len(d))}


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.atomic import atomic_path

    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 3.8), squeeze=False)
    for ax, (runs, by_gns) in zip(axes[0], results.items()):
        for k, s in enumerate(by_gns.values()):
            x = np.full(len(s["cases"]), k) + np.linspace(-0.15, 0.15, len(s["cases"]))
            ax.scatter(x, s["cases"], s=14, alpha=0.7)
            ax.errorbar(k + 0.3, s["runout_mse_mean"], yerr=s["runout_mse_se"], fmt="ks", capsize=4)
        ax.set_xticks(range(len(by_gns)), list(by_gns))
        ax.set_yscale("log")
        ax.set_ylabel("rollout runout MSE (L*^2)")
        ax.set_title(f"held-out runs of the {runs} model")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dag", required=True, help="a finished default DAG's folder")
    parser.add_argument("--out", default=None, help="default DAG/results/shared_gns")
    parser.add_argument("--base", default="quartz_multiple")
    parser.add_argument("--model", default="calibrated_quartz")
    parser.add_argument("--held-out", type=int, default=12, help="new DEM runs per model")
    parser.add_argument("--steps", type=int, default=None, help="training steps (default: the model GNS's)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0, help="not 0: all three GNSs trained with it")
    args = parser.parse_args()

    import torch
    import yaml

    from dem.atomic import write_json
    from dem.runout import RunoutMethod
    from gns.dataset import read_metadata
    from gns.train import train

    torch.set_num_threads(args.threads)
    dag = Path(args.dag).resolve()
    out = Path(args.out).resolve() if args.out else dag / "results/shared_gns"
    out.mkdir(parents=True, exist_ok=True)
    config = yaml.safe_load((dag / "config/config.yaml").read_text())
    runout = RunoutMethod.from_config(config.get("runout"))
    base = read_metadata(dag / "results/datasets" / args.base / "metadata.json")
    model = read_metadata(dag / "results/datasets" / args.model / "metadata.json")
    own = {name: dag / "results/gns" / name / "train/model_best.pt" for name in (args.base, args.model)}

    ranges = model["parameter_ranges"]
    names = dem_parameters(model)
    off = {k: 0.0 for k in names if k not in dem_parameters(base)}
    box_model = {k: ranges[k] for k in names}
    box_base = {**{k: base["parameter_ranges"][k] for k in dem_parameters(base)}, **{k: [v, v] for k, v in off.items()}}
    runs = {
        "base": test_paths(dag, base) + held_out_runs(dag, args.base, box_base, args.held_out, out / "dem/base", 1),
        "extended": test_paths(dag, model)
        + held_out_runs(dag, args.model, box_model, args.held_out, out / "dem/extended", 2),
    }

    metadata_path = out / "metadata.json"
    shared_metadata(dag, base, model, metadata_path)
    settings = training_settings(own[args.model], args.steps, args.seed)
    start = time.perf_counter()
    trained = train(metadata_path, out / "train", settings, runout=runout)
    train_s = time.perf_counter() - start
    own_train_s = {k: job_seconds(dag, k) for k in own}
    if args.seed:  # the DAG's GNSs are seed 0's: train both again with this seed, each at its own settings
        for name in own:
            start = time.perf_counter()
            metadata_own = dag / "results/datasets" / name / "metadata.json"
            settings_own = training_settings(own[name], args.steps, args.seed)
            train(metadata_own, out / f"own_{name}", settings_own, runout=runout)
            own_train_s[name] = round(time.perf_counter() - start, 1)
            own[name] = out / f"own_{name}" / "model_best.pt"

    results = {}
    for which, paths in runs.items():
        own_path = own[args.base] if which == "base" else own[args.model]
        by_gns = {}
        for gns, model_path in {"own": own_path, "shared": out / "train/model_best.pt"}.items():
            by_gns[gns] = summarise(score(model_path, paths, out / "rollouts" / gns, runout))
        by_gns["shared - own (paired)"] = paired(by_gns["shared"]["cases"], by_gns["own"]["cases"])
        results[which] = by_gns

    summary = {
        "dag": str(dag),
        "datasets": [args.base, args.model],
        "off_values": off,
        "settings": settings,
        "shared_best": trained.get("best"),
        "shared_train_s": round(train_s, 1),
        "seed": args.seed,
        "own_train_s": own_train_s,  # seed 0: the DAG's jobs (beside other jobs); else trained here
        "held_out": {k: [str(p) for p in v] for k, v in runs.items()},
        "results": results,
    }
    write_json(out / "summary.json", summary)
    plot({k: {g: s for g, s in v.items() if "cases" in s} for k, v in results.items()}, out / "shared_gns.png")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
