"""Numba's on-disk cache follows the kernels' code (dem.kernel_sources): dem/forces.py's kernels
inline dem/contact.py's contact law and dem/integrate.py's kernels link them, so a regression there
must reach the next process's runs and its ENGINE_VERSION, while a comment or docstring edit
changes neither."""

import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from tests.same_bits import ROOT

# restitution of a head-on pair of equal grains (e = 0.5), as tests/test_physics.py measures it
PROBE = """
import json, math
import dem
from dem.contact import restitution_factor
from dem.forces import ContactLaw
from dem.integrate import ENGINE_VERSION, State, run

radius, density, kn = 212.5e-6, 2650.0, 1e3
factor = restitution_factor(0.5)
law = ContactLaw(kn, 0.3 * kn, 0.5, factor, factor, 0.5, 0.5)
state = State.at_rest([[0.5, 0.5], [0.5 + 3 * radius, 0.5]], [radius, radius], density)
state.v[0, 0], state.v[1, 0] = 0.5, -0.5
contact_time = math.pi / math.sqrt(2 * kn / state.mass[0])
run(state, law, (0.0, 1.0, 0.0, math.inf), (-1.0, 2.0, -1.0, 2.0), contact_time / 50, 2000, gravity=0.0)
restitution = float(state.v[1, 0] - state.v[0, 0])
print(json.dumps({"package": dem.__file__, "version": ENGINE_VERSION, "restitution": restitution}))
"""


def measure(root) -> dict:
    """The probe's answer in a fresh interpreter that imports the dem package under `root`, numba
    caching beside it (dem/__pycache__)."""
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(root)
    proc = subprocess.run([sys.executable, "-c", PROBE], cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    answer = json.loads(proc.stdout.splitlines()[-1])
    assert answer["package"].startswith(str(root))
    return answer


def edit(path, old, new):
    text = path.read_text()
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new))


@pytest.mark.slow
def test_contact_law_edit_recompiles_integrate_kernels_and_a_comment_does_not(tmp_path):
    """Measured first in this tree, whose numba cache the copy then starts from (the same code: it
    loads), so that only the edited code compiles here."""
    before = measure(ROOT)
    assert before["restitution"] == pytest.approx(0.5, rel=0.02)
    shutil.copytree(ROOT / "dem", tmp_path / "dem", ignore=shutil.ignore_patterns("*.tmp.*", "*.pyc"))
    contact = tmp_path / "dem" / "contact.py"

    edit(contact, "kn * overlap + eta_n * normal_speed", "kn * overlap - eta_n * normal_speed")
    sabotaged = measure(tmp_path)
    assert sabotaged["version"] != before["version"]
    assert sabotaged["restitution"] > 1.5  # the dashpot now pushes the grains apart

    edit(contact, "kn * overlap - eta_n * normal_speed", "kn * overlap + eta_n * normal_speed  # spring, dashpot")
    edit(contact, "Repulsive normal force magnitude (N).", "The repulsive normal force (N).")
    reverted = measure(tmp_path)
    assert (reverted["version"], reverted["restitution"]) == (before["version"], before["restitution"])


def test_every_dem_kernel_is_keyed_on_its_sources():
    """A kernel compiled by numba's decorators directly would be cached against its own file only."""
    for path in (ROOT / "dem").rglob("*.py"):
        if path.name != "kernel_sources.py":
            assert not re.search(r"\bn?jit\b", path.read_text()), path
