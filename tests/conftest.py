import os
import time

import pytest
import torch

from dem.case import CollapseCase


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


TINY_ALL = "config/tiny_all.yaml"  # every stage at its smallest (tests/test_pipeline_end_to_end.py)


@pytest.fixture(scope="session")
def tiny_all_run(tmp_path_factory):
    """config/tiny_all.yaml's whole DAG, run once for the session in a copy of the workflow (shared
    by the end-to-end checks and the HTML report's): (workflow folder, {rule: jobs} Snakemake
    planned, wall seconds). E2E_CORES sets the cores (default 2)."""
    from tests.test_workflow import copy_workflow, job_stats, snakemake

    workdir = copy_workflow(tmp_path_factory.mktemp("tiny_all"))
    started = time.perf_counter()
    proc = snakemake(workdir, configfile=TINY_ALL, cores=int(os.environ.get("E2E_CORES", "2")), timeout=1200)
    return workdir, job_stats(proc.stderr), time.perf_counter() - started
