"""Does the GNS see each parameter (calibration.sensitivity): the plane fit's slopes against known
planes, and the verdicts a GNS blind to a parameter, a faithful one and a flat DEM must get."""

import numpy as np
import pytest
from scipy.stats import qmc

from calibration.sensitivity import parameter_sensitivity, response_slopes, sensitivity_record, untrusted_slopes

BOUNDS = [(0.3, 0.9), (0.3, 0.9), (28.0, 60.0)]  # mu, e and a Bond number: ranges of different size


def plane(points, slopes, noise=0.0, seed=0):
    """L* [n, 2] whose last column changes by slopes[j] across parameter j's bounds, plus noise."""
    low, high = np.asarray(BOUNDS).T
    last = 6.0 + ((points - low) / (high - low)) @ np.asarray(slopes, float)
    last = last + np.random.default_rng(seed).normal(0.0, noise, len(points))
    return np.column_stack([0.5 * last, last])


def box_points(n, seed):
    low, high = np.asarray(BOUNDS).T
    return low + qmc.LatinHypercube(d=3, seed=seed).random(n) * (high - low)


def test_slopes_are_the_change_across_the_bounds_with_an_honest_standard_error():
    points = box_points(30, 1)
    slopes, se = response_slopes(points, plane(points, [0.2, 1.5, -4.2])[:, -1], BOUNDS)
    assert np.allclose(slopes, [0.2, 1.5, -4.2], atol=1e-9) and np.all(se < 1e-9)
    # with noise 0.5, the truth lies within 3 standard errors (the error is the noise's, not zero)
    noisy, se = response_slopes(points, plane(points, [0.2, 1.5, -4.2], noise=0.5, seed=3)[:, -1], BOUNDS)
    assert np.all(np.abs(noisy - [0.2, 1.5, -4.2]) < 3 * se) and np.all((0.1 < se) & (se < 0.6))
    # a point whose rollout failed (NaN) is left out, not allowed to turn every slope into NaN
    failed = plane(points, [0.2, 1.5, -4.2])[:, -1]
    failed[[3, 17]] = np.nan
    slopes, se = response_slopes(points, failed, BOUNDS)
    assert np.allclose(slopes, [0.2, 1.5, -4.2], atol=1e-9) and np.all(np.isfinite(se))
    with pytest.raises(ValueError, match="cannot fit a plane"):
        response_slopes(points[:4], np.zeros(4), BOUNDS)
    with pytest.raises(ValueError, match="4 points with a finite value cannot fit"):
        response_slopes(points[:6], np.r_[np.zeros(4), np.nan, np.nan], BOUNDS)
    with pytest.raises(ValueError, match="do not span"):
        response_slopes(np.repeat(points[:1], 6, axis=0), np.zeros(6), BOUNDS)


def test_a_gns_blind_to_the_bond_number_is_caught_and_a_faithful_one_is_not():
    """The session-12 case: the DEM's L* falls by 4.2 across the Bond number, the GNS's stays put;
    mu moves neither (nothing to resolve); e moves both alike."""
    dem_points, gns_points = box_points(30, 1), box_points(40, 2)
    dem = plane(dem_points, [0.1, 1.5, -4.2], noise=0.5, seed=4)
    blind = plane(gns_points, [0.0, 1.2, 0.1], noise=0.15, seed=5)
    mu, e, bond = parameter_sensitivity(
        ["friction", "restitution", "bond_number"], BOUNDS, dem_points, dem, gns_points, blind
    )
    assert mu.resolved is None and "hardly responds" in mu.why
    assert e.resolved is True and e.why == ""
    assert bond.resolved is False and "does not resolve" in bond.why and "-4." in bond.why
    faithful = plane(gns_points, [0.0, 1.2, -3.5], noise=0.15, seed=5)
    assert [r.resolved for r in parameter_sensitivity("abc", BOUNDS, dem_points, dem, gns_points, faithful)] == [
        None,
        True,
        True,
    ]
    # the wrong sign, or more than twice the DEM's response, is not resolved either
    for slope in (+4.2, -9.0):
        wrong = plane(gns_points, [0.0, 1.2, slope], noise=0.15, seed=5)
        assert parameter_sensitivity("abc", BOUNDS, dem_points, dem, gns_points, wrong)[2].resolved is False
    # a GNS whose few, noisy points put its slope outside the band but within its error is not
    # flagged: that needs evidence too
    few = box_points(8, 6)
    unsure = parameter_sensitivity("abc", BOUNDS, dem_points, dem, few, plane(few, [0.0, 1.2, 3.0], 2.0, 7))[2]
    assert unsure.resolved is None and "too uncertain" in unsure.why and unsure.gns_se > 1.0


def test_a_gns_that_responds_where_the_dem_is_flat_is_gns_only():
    """The 2026-11-30 quartz case: the DEM's L* hardly moves across mu (+0.07 +- 0.35), the GNS's by
    +1.1, beyond its own error and the DEM slope's 95% interval but under 3 standard errors of the
    difference: not `resolved: False`, yet the GNS's mu interval rests on a response the DEM does
    not show."""
    dem_points, gns_points = box_points(30, 1), box_points(40, 2)
    dem = plane(dem_points, [0.1, 3.5, -4.2], noise=0.5, seed=4)
    gns = plane(gns_points, [1.5, 3.0, -4.0], noise=0.3, seed=5)
    mu, e, bond = parameter_sensitivity("abc", BOUNDS, dem_points, dem, gns_points, gns)
    assert mu.dem_se > 0.25 and abs(mu.dem) < 3 * mu.dem_se  # the DEM is flat within its error
    assert abs(mu.gns - mu.dem) < 3 * np.hypot(mu.gns_se, mu.dem_se)  # the difference alone is no flag
    assert mu.resolved is None and mu.gns_only and "the GNS does" in mu.why
    assert not e.gns_only and not bond.gns_only
    # the posterior leaves mu's slope out (calibration.inverse), e and the Bond number's in
    record, _ = sensitivity_record("abc", BOUNDS, (dem_points, dem), (gns_points, gns))
    assert untrusted_slopes(record) == {"a": mu.why} and untrusted_slopes(None) == {}
    # a GNS as flat as the DEM is not gns_only, nor one inside the DEM slope's 95% interval (the DEM
    # too uncertain to call that response, but showing it)
    for slope in (0.0, 0.8):
        within = plane(gns_points, [slope, 3.0, -4.0], noise=0.3, seed=5)
        response = parameter_sensitivity("abc", BOUNDS, dem_points, dem, gns_points, within)[0]
        assert abs(response.gns - response.dem) < 1.96 * response.dem_se and not response.gns_only
