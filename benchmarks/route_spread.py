"""Every calibration route's spread over its own randomness, from one finished default DAG; prints JSON.

    python benchmarks/route_spread.py DAG [--gns-seeds 1 2] [--calibration-seeds 1 2]
        [--diagnosis-seeds 1] [--aten default] [--column quartz] [--cores 1] [--collect]

DAG: the folder of a finished `bash run.sh main` (its results/ and .snakemake/metadata, its .venv).
Each variant is a hard-linked copy of it, DAG.spread/<variant>, in which Snakemake reruns only the
route that variant perturbs, at autogroup nice 19 (outputs are replaced, never written through, and
the job times are copies, so DAG itself is left as it was):
  - gns<S>[-<aten>]: the model's GNS of `--column` trained afresh with seed S (gns.per_dataset
    .<first dataset>.seed, which the model's GNS inherits), optionally under ATEN_CPU_CAPABILITY
    `--aten`, then its inverse design, DEM confirmation and correction, and validation;
  - cal<S>: calibration.seed S: the model DoE's (CCD, full factorial) and BO's packing and the BO's
    initial design, for every measured column, each validated;
  - dia<S>: diagnosis.seed S: the diagnosis' design runs and emulator, then its contenders check,
    the model it chooses and the diagnosis fit of that model, validated, for every measured column.
--collect: run nothing, read the variants there are (those whose Snakemake run ended well, its exit
status in DAG.spread/<variant>/spread.rc; the others are listed as unfinished). The JSON gives, per
column and route key, the validated MSE and its SE (on calibration.validation_packings packings)
and the point, for DAG (seed 0) and every variant, with the mean and range over them; and per
variant the lowest validated route of the model and GNS minus each DoE route (the verdict the
report draws).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

ROUTES_OF = {
    "gns": ("model-inverse",),
    "cal": ("model-doe", "model-doe-ff", "model-bayesopt"),
    "dia": ("diagnosis-model",),
}


def copy_dag(dag: Path, to: Path) -> None:
    """A hard-linked copy of the DAG folder (not its .venv, .git or Snakemake state but its job
    records; its job times copied), with a link to its .venv; a GNS training's checkpoints are
    dropped, so none resumes."""
    if to.exists():
        shutil.rmtree(to)
    to.mkdir(parents=True)
    job_times = dag / "results" / "benchmarks"

    def link(source, target):  # Snakemake writes a job's benchmark file in place, through a link
        (shutil.copy2 if Path(source).is_relative_to(job_times) else os.link)(source, target)

    for item in dag.iterdir():
        if item.name in (".venv", ".git", ".snakemake"):
            continue
        if item.is_dir():
            shutil.copytree(item, to / item.name, copy_function=link, symlinks=True)
        else:
            os.link(item, to / item.name)
    shutil.copytree(dag / ".snakemake" / "metadata", to / ".snakemake" / "metadata")
    (to / ".venv").symlink_to(dag / ".venv")
    for checkpoint in (to / "results" / "gns").glob("calibrated_*/train/checkpoint_last*.pt"):
        checkpoint.unlink()


def run_variant(dag: Path, variant: str, seed: int, aten: str | None, column: str, cores: int) -> int:
    """Snakemake's exit status for one variant's reruns (module docstring) in DAG.spread/<variant>."""
    config = yaml.safe_load((dag / "config" / "config.yaml").read_text())
    where = dag.parent / f"{dag.name}.spread" / variant
    copy_dag(dag, where)
    if variant.startswith("gns"):
        first = config["gns"]["datasets"][0]
        per_dataset = {**config["gns"].get("per_dataset", {}), first: {"seed": seed}}
        override = f"gns={json.dumps({'per_dataset': per_dataset})}"
        targets = [f"results/calibrated/{column}/validation/model-inverse.json"]
        force = ["gns_train"]
    elif variant.startswith("cal"):
        override = f"calibration={json.dumps({'seed': seed})}"
        targets = [f"results/calibrated/{c}/validation/{r}.json" for c in config["measured"] for r in ROUTES_OF["cal"]]
        force = ["calibrated_doe", "calibrated_bayesopt"]
    else:
        override = f"diagnosis={json.dumps({'seed': seed})}"
        targets = [f"results/calibrated/{c}/validation/diagnosis-model.json" for c in config["measured"]]
        force = ["diagnosis_library", "diagnosis"]
    env = dict(os.environ, **({"ATEN_CPU_CAPABILITY": aten} if aten else {}))
    command = [
        str(where / ".venv" / "bin" / "python"), "-m", "snakemake", *targets,
        "--profile", "workflow/profiles/default", "--cores", str(cores),
        "--rerun-triggers", "mtime", "input", "--forcerun", *force, "--config", override,
    ]  # fmt: skip
    with open(where / "spread.log", "w") as log:
        nice = 'echo 19 > /proc/self/autogroup 2>/dev/null; exec "$@"'
        status = subprocess.call(["sh", "-c", nice, "sh", *command], cwd=where, env=env, stdout=log, stderr=log)
    (where / "spread.rc").write_text(f"{status}\n")  # collect reads finished variants only
    return status


def validations(folder: Path, keys: tuple[str, ...] | None = None) -> dict:
    """{column: {route key: {mse, se, model, parameters}}} of a DAG folder's validated routes (those
    of `keys` only, where given)."""
    out: dict = {}
    for path in sorted(folder.glob("results/calibrated/*/validation/*.json")):
        if keys is not None and path.stem not in keys:
            continue
        v = json.loads(path.read_text())
        out.setdefault(path.parent.parent.name, {})[v["key"]] = {
            "mse": v["mse"],
            "se": v["mse_se"],
            "model": v["model"],
            "parameters": v["parameters"],
        }
    return out


def verdicts(routes: dict) -> dict:
    """The lowest validated route of the model, and GNS minus each DoE route (validated MSE)."""
    model = routes.get("model-doe", next(iter(routes.values())))["model"]
    own = {k: r for k, r in routes.items() if r["model"] == model}
    out = {"lowest": min(own, key=lambda k: own[k]["mse"])}
    if "model-inverse" in own:
        gns = own["model-inverse"]["mse"]
        out["gns_minus_doe"] = {k: gns - r["mse"] for k, r in own.items() if k.startswith("model-doe")}
    return out


def collect(dag: Path) -> dict:
    """The JSON of the module docstring, from DAG and the variants beside it."""
    spread = dag.parent / f"{dag.name}.spread"
    variants, unfinished = {"dag": validations(dag)}, []
    for folder in sorted(spread.glob("*")) if spread.exists() else []:  # only the routes it reran
        rc = folder / "spread.rc"
        if not rc.exists() or rc.read_text().strip() != "0":
            unfinished.append(folder.name)  # still running, or Snakemake failed: its copies are the DAG's
            continue
        variants[folder.name] = validations(folder, ROUTES_OF[folder.name[:3]])
    summary: dict = {}
    for name, columns in variants.items():
        for column, routes in columns.items():
            for key, route in routes.items():
                summary.setdefault(column, {}).setdefault(key, {})[name] = route["mse"]
    for column in summary:
        for by_variant in summary[column].values():
            values = list(by_variant.values())
            by_variant["mean"] = sum(values) / len(values)
            by_variant["range"] = [min(values), max(values)]
    # a variant reruns some routes: its verdict takes the others from the DAG it was copied from
    verdict = {
        name: {c: verdicts({**variants["dag"][c], **routes}) for c, routes in columns.items() if c in variants["dag"]}
        for name, columns in variants.items()
    }
    return {"dag": str(dag), "variants": variants, "unfinished": unfinished, "mse": summary, "verdicts": verdict}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dag", type=Path)
    parser.add_argument("--gns-seeds", type=int, nargs="*", default=[])
    parser.add_argument("--calibration-seeds", type=int, nargs="*", default=[])
    parser.add_argument("--diagnosis-seeds", type=int, nargs="*", default=[])
    parser.add_argument("--aten", default=None, help="ATEN_CPU_CAPABILITY for the GNS variants")
    parser.add_argument("--column", default="quartz", help="the column whose model GNS is retrained")
    parser.add_argument("--cores", type=int, default=1)
    parser.add_argument("--collect", action="store_true", help="only read the variants there are")
    args = parser.parse_args(argv)
    dag = args.dag.resolve()
    if not args.collect:
        suffix = f"-{args.aten}" if args.aten else ""
        runs = [(f"gns{s}{suffix}", s) for s in args.gns_seeds] + [(f"cal{s}", s) for s in args.calibration_seeds]
        runs += [(f"dia{s}", s) for s in args.diagnosis_seeds]
        for variant, seed in runs:
            status = run_variant(dag, variant, seed, args.aten, args.column, args.cores)
            print(f"{variant}: snakemake exit {status}", file=sys.stderr)
    print(json.dumps(collect(dag), indent=1))


if __name__ == "__main__":
    main()
