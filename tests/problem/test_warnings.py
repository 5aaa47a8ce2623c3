"""Warnings for weak geometry, and non-convergence as an error."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import ConvergenceError
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.sim import make_rig_placements, prius_like_rig, simulate


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(11)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 20), rng=rng, reference="lidar1")


def test_few_shared_boards_are_reported(sim):
    # lidar and camera share only two of the boards that both saw
    ds = sim.dataset
    both = np.flatnonzero(ds.sensor("lidar1").valid & ds.sensor("camera1").valid)
    radar = np.flatnonzero(ds.sensor("radar1").valid)
    keep = set(both[:2]) | set(radar)
    drop_cam = [k for k in range(ds.num_boards) if k not in set(both[:2])]
    ds2 = ds.with_excluded({"camera1": drop_cam}).select_boards(sorted(keep))
    r = calibrate(ds2, CalibrationOptions(mode="fcpe", detect_outliers=False))
    assert any("lidar1-camera1 shares only 2 board" in w for w in r.warnings), r.warnings


def test_collinear_boards_are_reported(sim):
    # keep boards whose reflectors lie (nearly) on one line: the same distance band, left-right
    ds = sim.dataset
    lidar = ds.sensor("lidar1")
    ks = np.flatnonzero(lidar.valid & ds.sensor("radar1").valid & ds.sensor("camera1").valid)
    centres = lidar.points[ks].mean(axis=1)
    # project onto the best-fit line and keep the 4 boards closest to it
    c0 = centres.mean(axis=0)
    u = np.linalg.svd(centres - c0)[2][0]
    off = np.linalg.norm((centres - c0) - np.outer((centres - c0) @ u, u), axis=1)
    chosen = ks[np.argsort(off)[:3]]
    r = calibrate(ds.select_boards(chosen), CalibrationOptions(mode="fcpe", detect_outliers=False))
    assert any("lidar1-radar1" in w and "nearly collinear" in w for w in r.warnings), r.warnings
    # and the radar's in-plane pose becomes weak too: reported with its std
    assert any(w.startswith("radar1: weakly observable") for w in r.warnings), r.warnings


def test_well_spread_boards_give_no_geometry_warning(sim):
    r = calibrate(sim.dataset, CalibrationOptions(mode="fcpe"))
    assert not any("collinear" in w or "shares only" in w for w in r.warnings), r.warnings


def test_pse_noise_non_convergence_is_an_error(sim):
    with pytest.raises(ConvergenceError, match="noise estimates did not converge"):
        calibrate(sim.dataset, CalibrationOptions(mode="pse", max_noise_iterations=1))
