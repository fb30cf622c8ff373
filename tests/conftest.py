import os
import time
from pathlib import Path

import pytest
import torch

from dem.case import CollapseCase
from dem.collapse import simulate_collapse
from dem.trajectory import write_trajectory
from gns.dataset import build_dataset
from tests.test_compare import tiny_case


@pytest.fixture
def small_case():
    """A coarse-grained quartz column (~270 grains) that collapses in about two seconds."""
    return CollapseCase(
        "quartz",
        L_i=0.02,
        aspect_ratio=1.0,
        friction=0.5,
        restitution=0.65,
        size_scale=3.0,
        seed=3,
        name="small",
    )


@pytest.fixture(scope="module")
def one_torch_thread():
    """Tiny graphs: one torch thread is faster than two and does not spin against other jobs."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# The tiny column's DEM runs (mu, e) of the GNS inverse-design tests (tests/test_inverse.py,
# tests/test_gns_recovery.py): spread over the paper's box; the last is the valid and test split.
TINY_RUNS = [(0.3, 0.3), (0.9, 0.9), (0.45, 0.8), (0.6, 0.5), (0.75, 0.65), (0.85, 0.4)]


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """Tiny DEM runs (TINY_RUNS) as a dataset: (metadata path, [trajectories])."""
    folder = tmp_path_factory.mktemp("inverse")
    trajectories, paths = [], []
    for k, (mu, e) in enumerate(TINY_RUNS):
        trajectory = simulate_collapse(tiny_case(mu, e, seed=k))
        paths.append(str(folder / f"case_{k}.h5"))
        write_trajectory(paths[-1], trajectory)
        trajectories.append(trajectory)
    build_dataset({"train": paths[:-1], "valid": paths[-1:], "test": paths[-1:]}, folder / "metadata.json", "tiny")
    return str(folder / "metadata.json"), trajectories


TINY_ALL = "config/tiny_all.yaml"  # every stage at its smallest (tests/test_pipeline_end_to_end.py)
# The column the tiny DAG calibrates, as a user brings one (README "Calibrate your own column"): a
# CSV outside the workflow, of a material of its own (not in dem.case.MATERIALS), given on the
# command line in place of config/tiny_all.yaml's own curve. The curve and geometry are those of
# data/test/tiny_quartz_a2.csv; the grains are quartz-sized, so the DEM costs what quartz's does.
OWN_MATERIAL = {"name": "glass", "diameter": 425e-6, "density": 2500.0, "solid_fraction": 0.6}


def write_own_column(path) -> str:
    """data/test/tiny_quartz_a2.csv as a column of OWN_MATERIAL, written to `path`; returns the path."""
    name, own = OWN_MATERIAL["name"], ",".join(str(OWN_MATERIAL[k]) for k in ("diameter", "density", "solid_fraction"))
    text = (Path(__file__).parents[1] / "data/test/tiny_quartz_a2.csv").read_text()
    rows = [line for line in text.splitlines() if not line.startswith("#")]
    lines = [rows[0] + ",grain_diameter,density,solid_fraction"]
    lines += [row.replace("tiny_quartz_a2,quartz,", f"{name}_a2,{name},") + f",{own}" for row in rows[1:]]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.fixture(scope="session")
def tiny_all_run(tmp_path_factory):
    """config/tiny_all.yaml's whole DAG, run once for the session in a copy of the workflow (shared
    by the end-to-end checks and the HTML report's) on a measured CSV the fixture writes outside it
    (write_own_column), given as the README tells a user: (workflow folder, {rule: jobs} Snakemake
    planned, wall seconds, the command line's --config arguments, which every later snakemake call
    on the folder repeats). E2E_CORES sets the cores (default 2)."""
    from tests.test_workflow import copy_workflow, job_stats, snakemake

    workdir = copy_workflow(tmp_path_factory.mktemp("tiny_all"))
    csv = write_own_column(tmp_path_factory.mktemp("own_column") / "glass_a2.csv")
    own = ("--config", f"measured={{tiny: {csv}}}")  # --config takes several values: the last option
    started = time.perf_counter()
    proc = snakemake(workdir, *own, configfile=TINY_ALL, cores=int(os.environ.get("E2E_CORES", "2")), timeout=1200)
    return workdir, job_stats(proc.stderr), time.perf_counter() - started, own


# `run.sh test` runs the suite on two workers (pytest-xdist, --dist loadfile): a test file runs on one
# worker, so a module's fixture (a DAG, a design library) runs once; the files that share the
# session's tiny_all DAG are one unit, so it runs once too. (xdist's loadgroup marks do not reach
# its scheduler under pytest 9, which no longer reads the node id xdist rewrites.)
SHARED_UNITS = {
    "tests/test_html_report.py": "tiny_all",
    "tests/test_pipeline_end_to_end.py": "tiny_all",
    "tests/test_same_answer.py": "tiny_all",
}


# The longest units first (seconds alone on 2 cores, 2026-11-30): each worker takes the next unit
# when it is free, so a long one started last would hold the suite up alone.
LONGEST_FIRST = (
    "tests/test_html_report.py",  # with test_pipeline_end_to_end.py: the tiny_all DAG, ~170 s
    "tests/test_pipeline_end_to_end.py",
    "tests/test_same_answer.py",  # the tiny_all DAG a second time, ~110 s
    "tests/test_diagnosis.py",  # ~230 s
    "tests/test_campaign.py",  # a campaign through the tiny DAG, ~80 s
    "tests/test_workflow.py",  # ~100 s
    "tests/test_slurm.py",  # ~55 s
    "tests/test_liggghts.py",  # ~50 s
)


def pytest_collection_modifyitems(items):
    rank = {path: k for k, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))  # stable: files keep their order


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SharedFixtureScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid):
            path = super()._split_scope(nodeid)
            return SHARED_UNITS.get(path, path)

    return SharedFixtureScheduling(config, log)
