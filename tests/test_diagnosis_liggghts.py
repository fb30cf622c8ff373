"""Another solver's data: a hidden mechanism in LIGGGHTS data is named by the diagnosis,
unchanged. Its own file so that, on CI's two workers (`--dist loadfile`), it runs beside
tests/test_diagnosis.py rather than after it; the library and settings are that file's."""

import json
import shutil

import numpy as np
import pytest

from calibration.design_runs import DEMRunner
from calibration.diagnosis import diagnose
from calibration.mechanisms import get_mechanisms
from calibration.observables import Observables
from calibration.synthetic import LAB_RUNOUT, draw_truth, evidence_margins, liggghts_measurement
from tests.test_diagnosis import CI_SETTINGS, MECHANISMS, PROFILE_NOISE, RUNOUT_NOISE, cached_library

LIGGGHTS_CASE = "cohesion"  # the mechanism of the CI's LIGGGHTS case (the benchmark runs all three and the null)


def test_a_hidden_mechanism_in_liggghts_data_is_named():
    """One hidden case simulated by LIGGGHTS with a Hertz contact law, SJKR cohesion, a packing it
    settles itself and the runout read as a lab would (calibration.synthetic.liggghts_measurement),
    diagnosed unchanged: the mechanism is named. The data state the lab's reading, so the diagnosis
    reads its own runs that way, from a CI library of its own (`cached_library`, columns stating
    LAB_RUNOUT). benchmarks/diagnosis_liggghts.py runs every mechanism the deck models, the null
    and thresholds."""
    if shutil.which("liggghts") is None:
        pytest.skip("liggghts not installed (Debian: apt-get install liggghts): no other solver to make the data")
    columns, library, _ = cached_library("lab_library", LAB_RUNOUT.method)
    rng = np.random.default_rng(1700)  # fixed before any verdict was seen
    truth = draw_truth(rng, MECHANISMS[LIGGGHTS_CASE])
    data, _ = liggghts_measurement(
        truth, columns, get_mechanisms(), CI_SETTINGS.simulation, RUNOUT_NOISE, PROFILE_NOISE, rng
    )
    assert all(c.grain_diameter == pytest.approx(5 * 425e-6) for c in data)
    assert all(c.runout_method == LAB_RUNOUT.method for c in data)  # the reading, as the data state it
    runner = DEMRunner(Observables(columns, CI_SETTINGS.runout), CI_SETTINGS.simulation)
    result = diagnose(data, CI_SETTINGS, library=library, runner=runner, name="liggghts")
    print(truth, result.cause, json.dumps(evidence_margins(result)))
    assert result.cause == LIGGGHTS_CASE, (truth, result.verdict, result.checks)
