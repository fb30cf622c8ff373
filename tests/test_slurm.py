"""The tiny DAG through snakemake-executor-plugin-slurm against a real single-node SLURM.

The test starts its own cluster as root (Debian slurm-wlm and munge; `bash run.sh test` installs
them): munged if none answers, slurmctld and slurmd in configless mode from a slurm.conf in a
temporary folder, on free ports. What works with this plugin (2.8.0) and no accounting database:
  - `--slurm-no-account`: without it the plugin asks `sacctmgr`, which needs slurmdbd;
  - `--slurm-status-command squeue`: `sacct` needs accounting; squeue sees finished jobs for
    MinJobAge (300 s here);
  - configless slurmd (`--conf-server`): the plugin's job step drops every SLURM_* variable,
    SLURM_CONF included, before its inner `srun`, so clients must find the config without it;
    slurmd caches it in /run/slurm/conf, where clients look.
Where the daemons cannot start (not root, not installed, no munge), the test skips saying why.
The dry run with the SLURM profile is in test_workflow.py and needs none of this.
"""

import contextlib
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dem.trajectory import read_attrs
from tests.test_workflow import copy_workflow, env

pytestmark = pytest.mark.slow
RUN_CONF = Path("/run/slurm/conf")
MUNGED_PID = Path("/run/munge/munged.pid")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def munge_works() -> bool:
    if not shutil.which("munge"):
        return False
    check = subprocess.run("munge -n | unmunge", shell=True, capture_output=True, timeout=10)
    return check.returncode == 0


def wait_for(predicate, seconds: float) -> bool:
    deadline = time.time() + seconds
    while time.time() < deadline:
        if predicate():
            return True
        time.sleep(0.3)
    return False


def stop(pid_file: Path):
    """Stop a daemon this test started, by the pid it wrote."""
    with contextlib.suppress(FileNotFoundError, ValueError, ProcessLookupError):
        pid = int(pid_file.read_text().split()[0])
        os.kill(pid, 15)
        wait_for(lambda: not Path(f"/proc/{pid}").exists(), 10)


@pytest.fixture
def slurm_cluster(tmp_path):
    """A one-node SLURM cluster with partition `test`; yields the sinfo output."""
    if os.geteuid() != 0:
        pytest.skip("starting slurmctld/slurmd needs root")
    missing = [b for b in ("slurmctld", "slurmd", "sbatch", "squeue", "munged") if not shutil.which(b)]
    if missing:
        pytest.skip(f"SLURM not installed (missing {missing}; Debian: apt-get install slurm-wlm munge)")
    if RUN_CONF.exists() and not RUN_CONF.is_symlink():
        pytest.skip(f"{RUN_CONF} belongs to a SLURM installation on this machine; not starting a test cluster")
    if shutil.which("sinfo") and subprocess.run(["sinfo"], capture_output=True, timeout=20).returncode == 0:
        pytest.skip("a SLURM cluster already answers here; not starting a second one")

    root = tmp_path / "slurm"
    for sub in ("state", "spool", "log", "run"):
        (root / sub).mkdir(parents=True)
    started_munged = False
    if not munge_works():
        Path("/run/munge").mkdir(parents=True, exist_ok=True)
        shutil.chown("/run/munge", "munge", "munge")
        key = Path("/etc/munge/munge.key")
        if not key.exists():
            subprocess.run(["mungekey", "--create"], capture_output=True, timeout=30)
        # default paths (/run/munge, /var/log/munge): the munge user cannot write to tmp_path
        started = subprocess.run(["runuser", "-u", "munge", "--", "munged"], capture_output=True, text=True, timeout=30)
        started_munged = started.returncode == 0
        if not wait_for(munge_works, 10):
            if started_munged:
                stop(MUNGED_PID)
            pytest.skip(f"munged does not answer: {started.stderr.strip()[-500:]} (see /var/log/munge/munged.log)")

    host = socket.gethostname()
    ctld_port, slurmd_port = free_port(), free_port()
    conf = root / "slurm.conf"
    conf.write_text(f"""ClusterName=gns4demtest
SlurmctldHost={host}
SlurmctldPort={ctld_port}
SlurmdPort={slurmd_port}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
SlurmctldParameters=enable_configless
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/run/slurmctld.pid
SlurmdPidFile={root}/run/slurmd.pid
SlurmctldLogFile={root}/log/slurmctld.log
SlurmdLogFile={root}/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MinJobAge=300
ReturnToService=2
MpiDefault=none
NodeName={host} CPUs={os.cpu_count()} RealMemory=4000 State=UNKNOWN
PartitionName=test Nodes={host} Default=YES MaxTime=INFINITE State=UP
""")
    daemon_env = dict(os.environ, SLURM_CONF=str(conf))
    client_env = {k: v for k, v in os.environ.items() if k != "SLURM_CONF"}
    try:
        ctld = subprocess.run(["slurmctld", "-i"], env=daemon_env, capture_output=True, text=True, timeout=30)
        if ctld.returncode != 0:
            pytest.skip(f"slurmctld cannot start: {ctld.stderr.strip()[-500:]}")
        slurmd = subprocess.run(
            ["slurmd", "--conf-server", f"{host}:{ctld_port}"],
            env=client_env,
            capture_output=True,
            text=True,
            timeout=30,
        )
        if slurmd.returncode != 0:
            pytest.skip(f"slurmd cannot start: {slurmd.stderr.strip()[-500:]}")

        def idle():
            out = subprocess.run(["sinfo", "-h", "-o", "%t"], env=client_env, capture_output=True, text=True)
            return out.returncode == 0 and "idle" in out.stdout

        if not wait_for(idle, 30):
            logs = "".join(
                (root / "log" / f).read_text()[-800:]
                for f in ("slurmctld.log", "slurmd.log")
                if (root / "log" / f).exists()
            )
            pytest.skip(f"the test SLURM node never became idle:\n{logs}")
        yield subprocess.run(["sinfo"], env=client_env, capture_output=True, text=True).stdout
    finally:
        stop(root / "run" / "slurmd.pid")
        stop(root / "run" / "slurmctld.pid")
        if started_munged:
            stop(MUNGED_PID)
        if RUN_CONF.is_symlink() and str(root) in os.readlink(RUN_CONF):
            RUN_CONF.unlink()


def test_tiny_dag_runs_through_the_slurm_executor(slurm_cluster, tmp_path):
    workdir = copy_workflow(tmp_path / "wf")
    target = "results/dem/tiny_multiple/trajectories/case_000.h5"
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "--configfile",
        "config/test.yaml",
        "--profile",
        "workflow/profiles/slurm",
        "--slurm-no-account",
        "--slurm-status-command",
        "squeue",
        "--slurm-init-seconds-before-status-checks",
        "1",
        "--default-resources",
        "slurm_partition=test",
        "mem_mb=500",
        "runtime=10",
        "--set-resources",
        "dem_packing:mem_mb=500",
        "dem_run:mem_mb=500",
        "--",
        target,
    ]
    run_env = {k: v for k, v in env().items() if k != "SLURM_CONF"}
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=400, env=run_env)
    assert proc.returncode == 0, proc.stderr[-4000:]
    attrs = read_attrs(workdir / target)
    assert attrs["engine"] == "builtin" and attrs["material"] == "copper"
    # the packing and the run went through sbatch (the deck is a local rule); the plugin deletes
    # the SLURM logs of successful jobs, so the evidence is its submit messages and the queue
    assert proc.stderr.count("has been submitted with SLURM jobid") == 2, proc.stderr[-4000:]
    queue = subprocess.run(
        ["squeue", "--states=all", "-h", "-o", "%j %T"], capture_output=True, text=True, env=run_env
    ).stdout
    assert queue.count("COMPLETED") >= 2, queue


def test_dem_jobs_ask_for_what_their_grains_need():
    """A DEM job's runtime and memory request scales with its grains and steps: the
    measured column at full scale asks for about an hour where the coarse default's asks for the
    minimum, two threads ask for less time, a retry for twice as much."""
    from pipeline.dem import MIN_RUNTIME_MIN, job_resources

    row = {"dataset": "quartz_multiple", "case_id": "case_000", "split": "train", "material": "quartz"}
    row |= {"L_i": 0.02, "aspect_ratio": 6.0, "friction": 0.39, "restitution": 0.54, "seed": 0}
    coarse, full = dict(row, size_scale=5.0), dict(row, size_scale=1.0)
    assert job_resources(coarse, "collapse")["runtime"] == MIN_RUNTIME_MIN
    one = job_resources(full, "collapse")
    # 14,718 grains x 1.13e6 steps at the requested 5e6 particle-steps/s: 55 min
    assert 50 <= one["runtime"] <= 60 and one["mem_mb"] > job_resources(coarse, "collapse")["mem_mb"]
    assert job_resources(full, "collapse", threads=2)["runtime"] < 0.65 * one["runtime"]
    assert job_resources(full, "collapse", attempt=2)["runtime"] == 2 * one["runtime"]
    assert MIN_RUNTIME_MIN < job_resources(full, "settle")["runtime"] < one["runtime"]
    with pytest.raises(ValueError, match="unknown stage 'run'"):
        job_resources(full, "run")
