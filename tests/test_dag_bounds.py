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


def load_dag_bounds():
    spec = importlib.util.spec_from_file_location("dag_bounds", ROOT / "benchmarks/dag_bounds.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
    dag_bounds = load_dag_bounds()

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


def test_a_job_of_two_threads_waits_for_both_cores_while_lower_jobs_fill_them(tmp_path):
    """A short job (priority 9), a 2-thread job (5) and a filler (0), all ready at once on 2 cores:
    the 2-thread job does not fit beside the short one, so the filler takes the other core and the
    2-thread job starts when both are free, at 30 s, and ends at 50 s. On 1 thread it starts at once
    and the filler after the short job: 10 + 30 s. Snakemake writes `threads: 2` in the log."""
    dag_bounds = load_dag_bounds()
    jobs = [
        {"output": ["x"], "input": [], "seconds": 10.0, "priority": 9},
        {"output": ["b"], "input": [], "seconds": 20.0, "priority": 5, "threads": 2},
        {"output": ["f"], "input": [], "seconds": 30.0, "priority": 0},
    ]
    assert dag_bounds.priority_schedule(jobs, cores=2) == 50.0
    assert dag_bounds.priority_schedule([dict(job, threads=1) for job in jobs], cores=2) == 40.0
    log = tmp_path / "run.log"
    log.write_text("localrule train:\n    output: m.pt\n    jobid: 2\n    threads: 2\n    priority: 5\n")
    assert [(job["threads"], job["priority"]) for job in dag_bounds.parse_jobs(log)] == [(2, 5)]


def test_what_if_replays_a_rule_on_other_threads_and_seconds(tmp_path):
    """The training of the first test on both cores for its 50 s: the figure waits for it, the answer
    after both: 2 + 50 + 30 + 8 s. A rule the log does not have is refused by name."""
    (tmp_path / "bench").mkdir()
    for rule, seconds in {"packing": 2.0, "train": 50.0, "figure": 30.0, "answer": 8.0}.items():
        (tmp_path / "bench" / f"{rule}.tsv").write_text(f"s\th:m:s\tcpu_time\n{seconds}\t0:00:01\t1.0\n")
    (tmp_path / "run.log").write_text(LOG)
    command = [sys.executable, ROOT / "benchmarks/dag_bounds.py", tmp_path / "run.log", "--root", tmp_path]
    out = subprocess.run([*command, "--what-if", "train=2:50"], capture_output=True, text=True, check=True)
    result = json.loads(out.stdout)
    assert result["priority_schedule_minutes"] == round(60 / 60, 1)
    assert result["what_if"] == {"train": {"threads": 2, "seconds": 50.0}}
    assert result["what_if_schedule_minutes"] == round(90 / 60, 1)
    bad = subprocess.run([*command, "--what-if", "trian=2:50"], capture_output=True, text=True, check=False)
    assert bad.returncode != 0 and "no timed job of rule trian" in bad.stderr
