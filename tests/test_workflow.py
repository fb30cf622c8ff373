"""The Snakemake workflow through its CLI, each test in its own copy of the workflow.

Runs the DEM and dataset stages of config/test.yaml (8 tiny cases in two datasets) with the
default profile, once for the module; the rerun test works on a copy of that finished run (mtimes
and .snakemake kept). The targets stop at this stage's outputs, so later stages (GNS, DoE, ...)
are not trained here; the report rule is checked by dry run and pipeline.report on these outputs.
"""

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from dem.grid import read_deck
from dem.trajectory import read_attrs, read_trajectory
from gns.dataset import load_dataset_metadata
from pipeline.report import assemble_report
from tests.same_bits import sha256_hdf5

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow
# this stage's outputs for config/test.yaml: the report fragment (needs both datasets) and figures
TARGETS = (
    ["results/report/dataset.md"]
    + [f"results/dem/tiny_friction/figures/case_{k:03d}.png" for k in range(5)]
    + [f"results/dem/tiny_multiple/figures/case_{k:03d}.png" for k in range(3)]
)


def copy_workflow(dest: Path) -> Path:
    """The workflow (Snakefile, rules, scripts, schemas, profiles, configs, data) copied into `dest`,
    modification times kept (Snakemake reruns a script rule whose script is newer than its outputs)."""
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy2(ROOT / "Snakefile", dest / "Snakefile")
    for folder in ("workflow", "config", "data"):  # data/: measured curves the configs name
        if (ROOT / folder).exists():
            shutil.copytree(ROOT / folder, dest / folder, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def env():
    # packages from this checkout, whatever the editable install maps
    return dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")


def snakemake(workdir, *args, timeout=300, check=True, configfile="config/test.yaml", cores=2, hash_seed=None):
    # --configfile takes several values: it goes before the options, targets go last
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "--configfile",
        configfile,
        "--profile",
        "workflow/profiles/default",
        "--cores",
        str(cores),
        *args,
    ]
    environment = env() if hash_seed is None else dict(env(), PYTHONHASHSEED=str(hash_seed))
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=timeout, env=environment)
    if check and proc.returncode != 0:
        raise AssertionError(
            f"snakemake {' '.join(args)} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}"
        )
    return proc


def job_stats(text: str) -> dict:
    """{rule: count} from the 'Job stats' table Snakemake prints before running (or dry-running)."""
    block = text.split("Job stats:", 1)[1].split("total", 1)[0]
    return {m[1]: int(m[2]) for m in re.finditer(r"^(\w+)\s+(\d+)\s*$", block, re.M)}


def mtimes(folder: Path) -> dict:
    return {p.relative_to(folder): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


def dem_bits(workdir: Path) -> dict:
    """{path: sha256 of its arrays} of tiny_friction's packings and trajectories, and its decks' JSON."""
    folder = workdir / "results/dem/tiny_friction"
    bits = {str(p.relative_to(folder)): sha256_hdf5(p) for p in sorted(folder.glob("[pt]*/case_*.h5"))}
    return bits | {str(p.relative_to(folder)): p.read_text() for p in sorted(folder.glob("decks/case_*.json"))}


FINISHED_BITS: dict = {}  # dem_bits of the finished run, taken before any test changes its config


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A complete run of the tiny DAG: the workflow folder."""
    workdir = copy_workflow(tmp_path_factory.mktemp("finished"))
    snakemake(workdir, *TARGETS)
    FINISHED_BITS.update(dem_bits(workdir))
    return workdir


def test_tiny_dag_builds_datasets_figures_and_report(finished):
    results = finished / "results"
    config = yaml.safe_load((finished / "config" / "test.yaml").read_text())
    for name, spec in config["datasets"].items():
        meta = load_dataset_metadata(results / "datasets" / name / "metadata.json")
        assert sum(len(v) for v in meta["splits"].values()) == spec["n_cases"]
        assert all(len(v) >= 1 for v in meta["splits"].values())
        assert meta["dt_frame"] == pytest.approx(spec["output_interval"])
        assert min(meta["velocity_std"]) > 0 and min(meta["acceleration_std"]) > 0
        for path in meta["splits"]["train"]:
            attrs = read_attrs(finished / path)
            assert attrs["engine"] == "builtin" and attrs["material"] == spec["material"]
        assert (results / "datasets" / name / "summary.png").stat().st_size > 10_000
        cases = (results / "datasets" / name / "cases.csv").read_text().splitlines()
        assert len(cases) == spec["n_cases"] + 1 and "final_L_star" in cases[0]
        for k in range(spec["n_cases"]):
            assert (results / "dem" / name / "figures" / f"case_{k:03d}.png").stat().st_size > 10_000
    # the report as the report rule assembles it, from this stage's fragment and benchmarks
    assemble_report(
        [("DEM datasets", results / "report/dataset.md")],
        results / "benchmarks",
        results / "report.md",
        "Test",
        results / "report/time_per_stage.png",
    )
    report = (results / "report.md").read_text()
    assert "## DEM datasets" in report and "## Time per stage" in report
    assert "| tiny_friction | 3/1/1 |" in report
    assert "| **dem** | all | 32 |" in report  # 8 cases x (deck, packing, run, figure)
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report):
        assert (results / link).exists(), link
    # every rule that ran left a log and a benchmark
    for rule in ("dem_deck", "dem_packing", "dem_run", "dem_figure"):
        assert len(list((results / "benchmarks" / "dem" / rule).rglob("*.tsv"))) == 8, rule
        assert len(list((results / "logs" / "dem" / rule).rglob("*.log"))) == 8, rule
    assert (
        "collapse tiny_friction/case_000: 100%" in (results / "logs/dem/dem_run/tiny_friction/case_000.log").read_text()
    )
    for rule in ("dataset", "dataset_summary"):
        assert len(list((results / "benchmarks" / "dataset" / rule).glob("*.tsv"))) == 2


def test_changing_one_case_reruns_only_its_jobs_and_dependents(finished, tmp_path):
    workdir = tmp_path / "changed"
    shutil.copytree(finished, workdir)
    unchanged = snakemake(workdir, "-n", *TARGETS)
    assert "Nothing to be done" in unchanged.stdout + unchanged.stderr
    config_path = workdir / "config" / "test.yaml"
    config = yaml.safe_load(config_path.read_text())
    config["datasets"]["tiny_friction"]["overrides"] = {"case_001": {"friction": 0.5}}
    config_path.write_text(yaml.safe_dump(config))
    before = mtimes(workdir / "results")

    dry = snakemake(workdir, "-n", *TARGETS)
    assert job_stats(dry.stdout) == {
        "dem_deck": 1,
        "dem_packing": 1,
        "dem_run": 1,
        "dem_figure": 1,
        "dataset": 1,
        "dataset_summary": 1,
        "dataset_section": 1,
    }
    snakemake(workdir, *TARGETS)
    after = mtimes(workdir / "results")
    changed = {str(p) for p in before if after.get(p) != before[p]}
    expected = {
        f"dem/tiny_friction/{kind}/case_001.{ext}"
        for kind, ext in (("decks", "json"), ("packings", "h5"), ("trajectories", "h5"), ("figures", "png"))
    }
    expected |= {
        "datasets/tiny_friction/metadata.json",
        "datasets/tiny_friction/summary.png",
        "datasets/tiny_friction/cases.csv",
        "report/dataset.md",
    }
    outputs = {p for p in changed if not p.startswith(("logs/", "benchmarks/"))}
    assert outputs == expected
    assert read_attrs(workdir / "results/dem/tiny_friction/trajectories/case_001.h5")["friction"] == 0.5
    assert read_attrs(workdir / "results/dem/tiny_friction/trajectories/case_002.h5")["friction"] != 0.5


def test_killed_run_resumes_recomputing_only_incomplete_jobs(finished, tmp_path):
    """Killed midway and resumed, in another clean copy with another hash seed: only the incomplete
    jobs run again, and the result is the same bits as the uninterrupted run's."""
    workdir = copy_workflow(tmp_path / "killed")
    target = "results/datasets/tiny_friction/metadata.json"
    trajectories = workdir / "results/dem/tiny_friction/trajectories"
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "--configfile",
        "config/test.yaml",
        "--profile",
        "workflow/profiles/default",
        "--cores",
        "2",
        target,
    ]
    log_path = tmp_path / "killed.log"
    finished_runs = 0
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            cmd,
            cwd=workdir,
            stdout=log,
            stderr=subprocess.STDOUT,
            env=dict(env(), PYTHONHASHSEED="7"),
            start_new_session=True,
        )
        try:
            deadline = time.time() + 240
            while finished_runs == 0 and time.time() < deadline and proc.poll() is None:
                time.sleep(0.05)
                finished_runs = log_path.read_text().count("(Rule: dem_run)")
        finally:
            # the whole process group, Snakemake and its running jobs, once one DEM run is
            # recorded as finished
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    existing = sorted(p.name for p in trajectories.glob("case_*.h5"))
    assert finished_runs >= 1 and len(existing) < 5, (
        f"kill came too early or too late to test a resume: {existing}\n{log_path.read_text()[-2000:]}"
    )
    for name in existing:  # whatever lies under an output name is a whole trajectory (atomic writes)
        case, _ = read_deck(workdir / "results/dem/tiny_friction/decks" / name.replace(".h5", ".json"))
        assert read_trajectory(trajectories / name).n_frames == case.n_frames
    before = mtimes(trajectories)

    snakemake(workdir, "--unlock", target)  # a killed run leaves its lock behind
    rerun = snakemake(workdir, target, hash_seed=7)
    recomputed = job_stats(rerun.stderr)["dem_run"]
    # runs Snakemake had recorded as finished are kept; missing ones and ones still marked
    # incomplete (output written, job not yet recorded) are run again
    assert 5 - len(existing) <= recomputed <= 5 - finished_runs
    after = mtimes(trajectories)
    kept = [p for p in before if p.suffix == ".h5" and not p.name.startswith(".") and after[p] == before[p]]
    assert len(kept) == 5 - recomputed
    # same bits: decks, packings and trajectories equal those of the uninterrupted run in `finished`
    assert len(FINISHED_BITS) == 15 and dem_bits(workdir) == FINISHED_BITS
    meta = load_dataset_metadata(workdir / target)
    assert sum(len(v) for v in meta["splits"].values()) == 5
    for paths in meta["splits"].values():
        for path in paths:
            read_trajectory(workdir / path)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda c: c["dem"].update(thread=2), "dem.thread: unknown key; allowed keys here: ['engine', 'figures', "),
        (lambda c: c["dem"].update(threads="two"), "dem.threads: 'two' has the wrong type; expected integer"),
        (
            lambda c: c["datasets"]["tiny_multiple"].update(restitution={"range": [0.3, 1.2]}),
            "datasets.tiny_multiple.restitution.range.1: 1.2 is out of range; allowed: > 0 and <= 1",
        ),
        (
            lambda c: c["gns"].update(datasets=["tiny_frction"]),
            "config key gns.datasets: 'tiny_frction' is not a dataset (datasets: ['tiny_friction', 'tiny_multiple'])",
        ),
    ],
    ids=["unknown-key", "wrong-type", "out-of-range", "cross-key"],
)
def test_bad_config_fails_before_any_job_runs(tmp_path, edit, message):
    workdir = copy_workflow(tmp_path / "bad")
    config = yaml.safe_load((workdir / "config" / "test.yaml").read_text())
    edit(config)
    (workdir / "config" / "test.yaml").write_text(yaml.safe_dump(config))
    proc = snakemake(workdir, check=False)
    assert proc.returncode != 0
    assert message in proc.stderr, proc.stderr[-3000:]
    assert not (workdir / "results").exists()


def test_paper_config_dry_run_has_700_cases(tmp_path):
    workdir = copy_workflow(tmp_path / "paper")
    cmd = [sys.executable, "-m", "snakemake", "-n", "--quiet", "rules", "--configfile", "config/paper.yaml"]
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=300, env=env())
    assert proc.returncode == 0, proc.stderr[-3000:]
    stats = job_stats(proc.stdout)
    for rule in ("dem_deck", "dem_packing", "dem_run", "dem_figure"):
        assert stats[rule] >= 700, stats
    assert stats["dataset"] == 5 and stats["report"] == 1  # 4 datasets and the calibrated model's GNS dataset


def test_slurm_profile_dry_run(tmp_path):
    """The SLURM profile parses and plans the DAG on any machine (no SLURM needed for -n)."""
    workdir = copy_workflow(tmp_path / "slurm_dry")
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "-n",
        "--profile",
        "workflow/profiles/slurm",
        "--configfile",
        "config/test.yaml",
    ]
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=300, env=env())
    assert proc.returncode == 0, proc.stderr[-3000:]
    stats = job_stats(proc.stdout)
    assert stats["dem_run"] == 8 and stats["report"] == 1 and stats["all"] == 1


def test_every_rule_declares_log_and_benchmark():
    """Convention of every stage (the report's time table reads the benchmark files)."""
    for smk in sorted((ROOT / "workflow" / "rules").glob("*.smk")):
        blocks = re.split(r"^(?=(?:rule|checkpoint) \w+:)", smk.read_text(), flags=re.M)[1:]
        for block in blocks:
            name = block.split(":", 1)[0]
            assert re.search(r"^    log:", block, re.M), f"{smk.name}: {name} has no log:"
            bench = re.search(r"^    benchmark:\s*\n\s+\"(results/benchmarks/[^/\"]+/[^\"]+\.tsv)\"", block, re.M)
            assert bench, f"{smk.name}: {name} has no benchmark: results/benchmarks/<stage>/<rule>/... .tsv"


def test_report_rebases_fragment_links_and_sums_benchmarks(tmp_path):
    fragment = tmp_path / "results/report/stage.md"
    fragment.parent.mkdir(parents=True)
    fragment.write_text("![fig](../stage/fig.png) [web](https://example.org/x.png) [top](#time-per-stage)\n")
    bench = tmp_path / "results/benchmarks/stage/rule_a"
    bench.mkdir(parents=True)
    header = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
    for k, seconds in enumerate((1.5, 2.5)):
        (bench / f"case_{k}.tsv").write_text(header + f"{seconds}\t0:00:01\t100.0\t1\t1\t1\t0\t0\t0\t1\n")
    text = assemble_report(
        [("Stage", fragment)],
        tmp_path / "results/benchmarks",
        tmp_path / "results/report.md",
        "T",
        tmp_path / "results/report/time.png",
    )
    assert "![fig](stage/fig.png)" in text and "(https://example.org/x.png)" in text and "(#time-per-stage)" in text
    assert "| stage | rule_a | 2 | 4.0 | 2.00 | 2.50 | 100 |" in text
    (bench / "broken.tsv").write_text("not a benchmark\n")
    with pytest.raises(ValueError, match=r"broken\.tsv: not a Snakemake benchmark file"):
        assemble_report(
            [("Stage", fragment)],
            tmp_path / "results/benchmarks",
            tmp_path / "results/report.md",
            "T",
            tmp_path / "results/report/time.png",
        )


def test_one_gns_runs_both_models_routes_in_the_default_dag(tmp_path):
    """calibration.gns_shared (the default config): the base model's inverse design reads the model's
    GNS, whose dataset holds the base model's runs too, and the base dataset trains no GNS of its
    own; turned off, each model trains its own. The base route through the shared GNS then waits on
    the model's chain, and goes first with it."""
    workdir = copy_workflow(tmp_path / "shared")
    target = "results/inverse/quartz/inverse.json"

    def dry_run(*config):
        cmd = [sys.executable, "-m", "snakemake", "-n", "all", target, "--configfile", "config/config.yaml", *config]
        proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=300, env=env())
        assert proc.returncode == 0, proc.stderr[-3000:]
        return proc.stdout

    def job(text, output):
        """The dry run's block of the job that writes `output`."""
        (block,) = [b for b in text.split("\nrule ") if f"\n    output: {output}" in b]
        return block

    def inputs(text, output):
        """The input line of the job that writes `output`."""
        return job(text, output).split("input: ", 1)[1].split("\n", 1)[0].split(", ")

    def priority(text, output):
        """The scheduling priority of the job that writes `output` (a dry run prints none for 0)."""
        block = job(text, output)
        return int(block.split("priority: ", 1)[1].split("\n", 1)[0]) if "priority: " in block else 0

    shared = dry_run()
    assert "results/gns/calibrated_quartz/train/model_best.pt" in inputs(shared, target)
    assert "results/gns/quartz_multiple/" not in shared
    dataset = inputs(shared, "results/datasets/calibrated_quartz/metadata.json")
    assert len([p for p in dataset if p.startswith("results/dem/quartz_multiple/trajectories/")]) == 30
    assert job_stats(shared)["gns_train"] == 1
    base_validation = "results/calibrated/quartz/validation/base-inverse.json"
    chain = priority(shared, "results/calibrated/quartz/inverse.json")
    assert chain > 0
    assert priority(shared, target) == priority(shared, base_validation) == chain
    own = dry_run("--config", "calibration={'gns_shared': False}")
    assert "results/gns/quartz_multiple/train/model_best.pt" in inputs(own, target)
    dataset = inputs(own, "results/datasets/calibrated_quartz/metadata.json")
    assert not [p for p in dataset if "quartz_multiple" in p]
    assert job_stats(own)["gns_train"] == 2
    # without the shared GNS the base route waits on its own GNS: the answer's priority, below the chain
    assert 0 < priority(own, target) == priority(own, base_validation) < chain
    for text in (shared, own):
        assert_no_job_waits_on_a_lower_priority(text)


def assert_no_job_waits_on_a_lower_priority(dry_run_text):
    """Every job's priority is at least that of each job that reads its outputs (common.smk's
    ANSWER_PRIORITY): a job left at a lower one starts after the fillers and holds its chain."""
    jobs = []
    for block in re.split(r"\n(?:local)?rule ", dry_run_text)[1:]:
        field = dict(re.findall(r"^    (input|output|priority): (.*)$", block, flags=re.M))
        jobs.append((block.split(":", 1)[0], field.get("input", "").split(", "), field.get("output", "").split(", "),
                     int(field.get("priority", 0))))  # fmt: skip
    assert len(jobs) > 100
    producer = {path: (rule, priority) for rule, _, outputs, priority in jobs for path in outputs if path}
    waiting = sorted(
        {(producer[p][0], producer[p][1], rule, priority) for rule, inputs, _, priority in jobs for p in inputs
         if p in producer and producer[p][1] < priority}
    )  # fmt: skip
    assert not waiting, f"(rule, its priority, a rule waiting on it, that one's priority): {waiting[:5]}"


def test_a_local_run_starts_its_jobs_without_snakemake_s_rate_limit(tmp_path):
    """The Snakefile's onstart drops the limiter of job starts from a local run. Under a limit of one
    job an hour three jobs would take two hours, and Snakemake's exit would wait for its timer; with
    the project's onstart they all run and Snakemake exits (a minute is ample: a few seconds here).
    The hook is read from the Snakefile, so the test follows it."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from scheduler_overhead import project_hook

    snakefile = project_hook() + '\n\nrule all:\n    input: expand("done/{k}", k=range(3))\n'
    snakefile += 'rule one:\n    output: "done/{k}"\n    shell: "touch {output}"\n'
    (tmp_path / "Snakefile").write_text(snakefile)
    command = [sys.executable, "-m", "snakemake", "--cores", "2", "--max-jobs-per-timespan", "1/1h"]
    proc = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "done").iterdir()) == ["0", "1", "2"]
