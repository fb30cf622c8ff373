"""benchmarks/route_spread.py: a variant counts only the routes it reran, the spread is over the DAG
and its variants, and the verdict of a variant takes the routes it did not rerun from the DAG."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def write_validation(folder: Path, column: str, key: str, mse: float, model: str = "sidewall_friction") -> None:
    path = folder / "results" / "calibrated" / column / "validation" / f"{key}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"key": key, "mse": mse, "mse_se": 0.01, "model": model, "parameters": {"friction": 0.5}}
    path.write_text(json.dumps(record))


def test_the_spread_counts_each_variants_own_routes_and_its_verdict(tmp_path):
    dag, spread = tmp_path / "dag", tmp_path / "dag.spread"
    for key, mse in {"model-inverse": 0.2, "model-doe": 0.1, "model-bayesopt": 0.15, "diagnosis-base": 3.0}.items():
        write_validation(dag, "quartz", key, mse, "base" if key == "diagnosis-base" else "sidewall_friction")
    # a GNS variant holds copies of every route, but reran only its own
    for key, mse in {"model-inverse": 0.05, "model-doe": 0.1, "model-bayesopt": 0.15}.items():
        write_validation(spread / "gns1", "quartz", key, mse)
    write_validation(spread / "cal1", "quartz", "model-doe", 0.3)
    write_validation(spread / "cal2", "quartz", "model-doe", 9.0)  # still running: not counted
    for variant in ("gns1", "cal1"):
        (spread / variant / "spread.rc").write_text("0\n")
    out = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "route_spread.py"), str(dag), "--collect"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    result = json.loads(out)
    assert result["unfinished"] == ["cal2"]
    mse = result["mse"]["quartz"]
    assert set(mse["model-inverse"]) == {"dag", "gns1", "mean", "range"}
    assert mse["model-inverse"]["mean"] == 0.125 and mse["model-inverse"]["range"] == [0.05, 0.2]
    assert set(mse["model-doe"]) == {"dag", "cal1", "mean", "range"} and mse["model-doe"]["range"] == [0.1, 0.3]
    verdicts = result["verdicts"]
    assert verdicts["dag"]["quartz"]["lowest"] == "model-doe"
    assert verdicts["gns1"]["quartz"]["lowest"] == "model-inverse"
    gns_minus_doe = {name: v["quartz"]["gns_minus_doe"]["model-doe"] for name, v in verdicts.items() if name != "cal1"}
    assert gns_minus_doe["gns1"] < 0 < gns_minus_doe["dag"]
    assert verdicts["cal1"]["quartz"]["lowest"] == "model-bayesopt"


def test_a_variants_copy_leaves_the_dags_job_times_as_they_were(tmp_path):
    """Snakemake writes a job's benchmark file in place: through a hard link, a variant's rerun would
    overwrite the DAG's own job time (dag_bounds and the routes' costs read them)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from route_spread import copy_dag

    dag = tmp_path / "dag"
    times = dag / "results" / "benchmarks" / "calibrated" / "calibrated_inverse" / "quartz.tsv"
    times.parent.mkdir(parents=True)
    times.write_text("s\n405.07\n")
    write_validation(dag, "quartz", "model-inverse", 0.2)
    (dag / ".snakemake" / "metadata").mkdir(parents=True)
    (dag / ".venv").mkdir()
    variant = tmp_path / "variant"
    copy_dag(dag, variant)
    with open(variant / times.relative_to(dag), "w") as out:  # in place, as Snakemake's benchmark
        out.write("s\n211.45\n")
    assert times.read_text() == "s\n405.07\n"
    validation = Path("results/calibrated/quartz/validation/model-inverse.json")
    assert (variant / validation).stat().st_ino == (dag / validation).stat().st_ino  # outputs still linked
