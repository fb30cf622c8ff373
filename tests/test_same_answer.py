"""The tiny DAG twice on one machine: a second Snakemake process, in a clean copy of the workflow,
with another PYTHONHASHSEED, writes the same JSON outputs as the session's run
(tests/conftest.py's tiny_all_run), every file and every value, wall times apart.

The second process starts from the first's DEM stage (results/dem: the datasets' settled packings
and runs), so that it pays for the stages downstream, not again for some 80 short DEM jobs whose
start-up is most of their cost: a DEM run repeats its bits in a fresh process and on another
processor's kernels by tests/test_physics.py, and every DEM run made inside a later job (the
diagnosis, the DoE, the validations, the calibrated model's dataset, which follows its model.json)
runs again here.

What this shows is bits on one machine: the same code and libraries on the same processor repeat
every number of every stage (the GNS trainings, GP fits, Bayesian optimisation, the DoE
regression, the diagnosis and its DEM runs, the answer). It says nothing of another processor, whose BLAS and torch
kernels may round otherwise: there a route's optimum can move within its own spread (README, "What
repeats, and where").
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from tests.conftest import TINY_ALL
from tests.test_workflow import copy_workflow, job_stats, snakemake

pytestmark = pytest.mark.slow
# Keys whose values are wall-clock measurements (seconds a run, a stage or an optimiser took, or the
# rates computed from them), by the names the stages give them: they differ between any two runs, so
# they are left out of the comparison.
TIMING_SUFFIXES = ("seconds", "_s", "_s_mean", "_per_second")


def is_timing(key: str) -> bool:
    return key.endswith(TIMING_SUFFIXES)


def json_outputs(workdir: Path) -> dict[str, object]:
    """{path under results/: its JSON, wall times left out} of every JSON a run of the DAG wrote
    (its logs apart); the run's own folder is written <workflow> wherever it appears."""
    results = workdir / "results"
    outputs = {}
    for path in sorted(results.rglob("*.json")):
        relative = str(path.relative_to(results))
        if relative.startswith("logs/"):
            continue
        text = path.read_text().replace(str(workdir), "<workflow>")
        outputs[relative] = without_timings(json.loads(text))
    return outputs


def without_timings(value):
    """`value` (parsed JSON) with every timing key (is_timing) removed, at any depth."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if not is_timing(k)}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def differences(first, second, where: str = "") -> list[str]:
    """Where two parsed JSON values differ: the key paths, with both values, of every difference."""
    if isinstance(first, dict) and isinstance(second, dict):
        out = [f"{where}/{k}: only in one" for k in sorted(set(first) ^ set(second))]
        for key in sorted(set(first) & set(second)):
            out += differences(first[key], second[key], f"{where}/{key}")
        return out
    if isinstance(first, list) and isinstance(second, list) and len(first) == len(second):
        return [d for k, (a, b) in enumerate(zip(first, second)) for d in differences(a, b, f"{where}[{k}]")]
    return [] if first == second else [f"{where}: {str(first)[:80]} != {str(second)[:80]}"]


def test_differences_name_every_changed_value_and_ignore_wall_times():
    first = {"a": [1, {"b": 2.0, "seconds": 3.1, "settle_s": {"mean": 1.0}}], "c": "x"}
    again = {"a": [1, {"b": 2.0, "seconds": 9.9, "settle_s": {"mean": 2.0}}], "c": "x"}
    assert differences(without_timings(first), without_timings(again)) == []
    moved = {"a": [1, {"b": 2.0000001, "seconds": 3.1, "settle_s": {"mean": 1.0}}], "c": "x"}
    assert differences(first, moved) == ["/a[1]/b: 2.0 != 2.0000001"]
    assert differences(first, {"a": [1], "c": "x"}) == [f"/a: {first['a']} != [1]"]
    assert without_timings({"n_runs": 3, "mse_s": 1}) == {"n_runs": 3}


def test_a_second_process_in_a_clean_folder_writes_the_same_json(tiny_all_run, tmp_path_factory):
    first, planned, _, own = tiny_all_run
    second = copy_workflow(tmp_path_factory.mktemp("tiny_all_again"))
    shutil.copytree(first / "results" / "dem", second / "results" / "dem")  # times kept: up to date
    cores = int(os.environ.get("E2E_CORES", "2"))  # as the first run's: a job's threads follow the cores
    proc = snakemake(second, *own, configfile=TINY_ALL, cores=cores, timeout=1200, hash_seed=12345)
    rerun = job_stats(proc.stderr)
    # the datasets' DEM jobs were taken over; the calibrated model's GNS dataset, whose cases follow
    # the model.json this run writes again, ran again
    assert 0 < rerun.get("dem_run", 0) < planned["dem_run"], (rerun.get("dem_run"), planned["dem_run"])
    ours, theirs = json_outputs(first), json_outputs(second)
    assert len(ours) > 30 and sorted(ours) == sorted(theirs)
    changed = {path: differences(ours[path], theirs[path])[:8] for path in ours if ours[path] != theirs[path]}
    assert not changed, json.dumps(changed, indent=1)
