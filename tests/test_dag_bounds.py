"""benchmarks/dag_bounds.py: the work bound and the critical path of a finished DAG run, read from
its Snakemake log and benchmark files."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LOG = """Building DAG of jobs...
[Tue Dec  1 08:00:00 2026]
localrule packing:
    output: a.h5
    jobid: 3
    benchmark: bench/packing.tsv
    wildcards: case=a
    resources: tmpdir=/tmp

[Tue Dec  1 08:00:01 2026]
localrule train:
    input: a.h5
    output: model.pt, curve.png
    jobid: 2
    benchmark: bench/train.tsv
    resources: tmpdir=/tmp

[Tue Dec  1 08:00:02 2026]
localrule figure:
    input: a.h5
    output: a.png
    jobid: 4
    benchmark: bench/figure.tsv

[Tue Dec  1 08:00:09 2026]
localrule answer:
    input: model.pt, a.png
    output: answer.json
    jobid: 1
    benchmark: bench/answer.tsv
"""


def test_the_critical_path_is_the_longest_chain_and_the_work_is_shared_by_the_cores(tmp_path):
    (tmp_path / "bench").mkdir()
    # the figure's job ran a second process beside it: more CPU than wall seconds
    cpu = {"packing": 1.0, "train": 25.0, "figure": 45.0, "answer": 4.0}
    for rule, seconds in {"packing": 2.0, "train": 50.0, "figure": 30.0, "answer": 8.0}.items():
        (tmp_path / "bench" / f"{rule}.tsv").write_text(f"s\th:m:s\tcpu_time\n{seconds}\t0:00:01\t{cpu[rule]}\n")
    (tmp_path / "run.log").write_text(LOG)
    out = subprocess.run(
        [sys.executable, ROOT / "benchmarks/dag_bounds.py", tmp_path / "run.log", "--root", tmp_path, "--cores", "2"],
        capture_output=True,
        text=True,
        check=True,
    )
    result = json.loads(out.stdout)
    assert result["jobs"] == 4 and result["work_job_seconds"] == 90.0 and result["work_cpu_seconds"] == 75.0
    # the training, not the figure beside it, lies on the path: 2 + 50 + 8 s
    assert [job["rule"] for job in result["critical_path"]] == ["packing", "train", "answer"]
    assert result["critical_path_minutes"] == round(60 / 60, 1)
    assert result["work_bound_minutes"] == round(90 / 2 / 60, 1) and result["cpu_bound_minutes"] == round(
        75 / 2 / 60, 1
    )
    assert result["lower_bound_minutes"] == 1.0 and result["target_reachable"]
    # no priorities in the log: its order; the figure beside the training, the answer after both
    assert result["priority_schedule_minutes"] == round(60 / 60, 1)


def test_the_priority_schedule_starts_a_long_chain_first_only_when_its_priority_says_so():
    """Two fillers and a short job before a long one, on 2 cores: the short job first (its priority
    above the fillers') ends at 10 + 60 s; at equal priority the log's order starts the fillers
    first and the long job ends at 20 + 60 s."""
    spec = importlib.util.spec_from_file_location("dag_bounds", ROOT / "benchmarks/dag_bounds.py")
    dag_bounds = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(dag_bounds)

    def jobs(first_priority):
        return [
            {"output": ["x"], "input": [], "seconds": 10.0, "priority": 0},
            {"output": ["y"], "input": [], "seconds": 10.0, "priority": 0},
            {"output": ["a"], "input": [], "seconds": 10.0, "priority": first_priority},
            {"output": ["b"], "input": ["a"], "seconds": 60.0, "priority": first_priority},
        ]

    assert dag_bounds.priority_schedule(jobs(5), cores=2) == 70.0
    assert dag_bounds.priority_schedule(jobs(0), cores=2) == 80.0
    assert dag_bounds.priority_schedule(jobs(0), cores=1) == 90.0
