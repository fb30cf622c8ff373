"""Start-up cost of a job: every Snakemake job is a fresh interpreter that imports its stage module,
and the default DAG runs ~400 of them. torch (~2 s to import) and scikit-learn (~1 s) belong to the
jobs that run a GNS or fit a GP, so the stage modules of every other job, and the modules the
Snakefile imports to parse the DAG, must load neither.
"""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# the jobs that roll a GNS out import these (pipeline.gns imports torch inside its functions)
GNS_JOBS = {"pipeline.calibrated_inverse", "pipeline.inverse_design"}
# what workflow/rules/*.smk import at parse time, besides the stage modules
SNAKEFILE_IMPORTS = ["dem.grid", "dem.runout", "dem.scale_ladder", "calibration.diagnosis", "doe.design", "doe.study"]


def test_stage_modules_of_dem_jobs_load_neither_torch_nor_sklearn():
    stages = sorted(f"pipeline.{p.stem}" for p in (ROOT / "pipeline").glob("*.py") if p.stem != "__init__")
    light = [m for m in stages if m not in GNS_JOBS] + SNAKEFILE_IMPORTS
    assert len(light) > 15  # the glob found the stage layer
    code = (
        "import importlib, sys\n"
        f"for name in {light!r}:\n"
        "    importlib.import_module(name)\n"
        "    heavy = [m for m in ('torch', 'sklearn') if m in sys.modules]\n"
        "    if heavy:\n"
        "        sys.exit(f'{name} loads {heavy}')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    # and the check can fail: a GNS job's module does load torch
    proc = subprocess.run(
        [sys.executable, "-c", "import sys, pipeline.inverse_design; assert 'torch' in sys.modules"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
