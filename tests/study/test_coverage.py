"""Pooling the motion-capture coverage benchmark's runs (rigcal.study.coverage.pool_mocap)."""

from __future__ import annotations

import pytest

from rigcal.errors import InputError
from rigcal.study.coverage import CHI2_95_3, CHI2_95_6, pool_mocap, wilson


def _run(seed: int, six: dict, three: dict | None = None, holds: int = 8, floor=(0.0, 0.0)) -> dict:
    data = {"seed": seed, "holds": holds, "hold_sigma_floor": list(floor), "nees_6dof": six}
    if three is not None:
        data["nees_3dof"] = three
    return data


def test_wilson_matches_the_published_intervals():
    # the n = 1 cases and the docs' 178 of 180
    assert wilson(1, 1) == pytest.approx((0.2065, 1.0), abs=5e-4)
    assert wilson(0, 1) == pytest.approx((0.0, 0.7935), abs=5e-4)
    assert wilson(178, 180) == pytest.approx((0.960, 0.997), abs=5e-4)
    assert wilson(0, 0) == (0.0, 1.0)


def test_pooling_counts_every_estimate_of_every_run_once():
    inside, outside = CHI2_95_6 - 1.0, CHI2_95_6 + 1.0
    a = _run(0, {"pixel": {"lidar": [inside, outside, 6.0], "camera": [inside]}},
             {"pixel": {"lidar": [1.0, CHI2_95_3 + 1, 2.0], "camera": [1.0]}})
    b = _run(1, {"pixel": {"lidar": [inside, 12.0]}, "hold_bias": {"camera": [outside, outside]}},
             {"pixel": {"lidar": [1.0, 1.0]}, "hold_bias": {"camera": [9.0, 1.0]}})
    got = pool_mocap([("a.json", a), ("b.json", b)])
    assert got["holds"] == 8 and got["seeds"] == [0, 1]
    lidar = got["models"]["pixel"]["lidar"]
    assert (lidar["checks"], lidar["inside_6dof"], lidar["checks_3dof"], lidar["inside_3dof_translation"]) == (5, 4, 5, 4)
    assert lidar["interval"] == wilson(4, 5)
    assert lidar["nees_median"] == pytest.approx(inside / 6)  # the median of all five
    assert lidar["nees_median_by_run"] == pytest.approx([inside / 6, (inside + 12.0) / 12])
    assert got["models"]["pixel"]["camera"]["checks"] == 1  # only run a has it
    cam = got["models"]["hold_bias"]["camera"]
    assert (cam["checks"], cam["inside_6dof"], cam["inside_3dof_translation"]) == (2, 0, 1)
    assert "lidar" not in got["models"]["hold_bias"] and "mixed" not in got["models"]


def test_the_errors_pool_over_the_runs_that_wrote_them_and_the_estimator_is_named():
    a = {**_run(0, {"pixel": {"lidar": [1.0, 2.0]}}), "estimator": "gls",
         "errors_m": {"pixel": {"lidar": [0.001, 0.003]}}}
    b = {**_run(1, {"pixel": {"lidar": [1.0]}}), "estimator": "gls"}  # no errors written
    got = pool_mocap([("a", a), ("b", b)])
    lidar = got["models"]["pixel"]["lidar"]
    assert got["estimator"] == "gls" and lidar["checks"] == 3 and lidar["checks_error"] == 2
    assert lidar["error_median_m"] == pytest.approx(0.002)
    # files written before the estimator was chosen were least squares'
    assert pool_mocap([("c", _run(0, {"pixel": {"lidar": [1.0]}}))])["estimator"] == "ls"


def test_the_translation_part_counts_only_the_runs_that_wrote_it():
    a = _run(0, {"pixel": {"lidar": [1.0]}}, {"pixel": {"lidar": [CHI2_95_3 + 1]}})
    b = _run(1, {"pixel": {"lidar": [1.0, 2.0]}})  # written before nees_3dof was
    lidar = pool_mocap([("a", a), ("b", b)])["models"]["pixel"]["lidar"]
    assert (lidar["checks"], lidar["checks_3dof"], lidar["inside_3dof_translation"]) == (3, 1, 0)


@pytest.mark.parametrize("second, words", [
    (_run(0, {"pixel": {"lidar": [1.0]}}), ["b.json", "a.json", "'pixel'", "seed 0"]),
    (_run(1, {"pixel": {"lidar": [1.0]}}, holds=4), ["holds", "a.json 8", "b.json 4"]),
    (_run(1, {"pixel": {"lidar": [1.0]}}, floor=(0.002, 0.001)), ["hold_sigma_floor", "b.json"]),
    ({**_run(1, {"pixel": {"lidar": [1.0]}}), "estimator": "gls"}, ["estimator", "a.json ls", "b.json gls"]),
    ({**_run(1, {}), "estimator": "wls"}, ["b.json", "'estimator'", "'wls'"]),
    ({**_run(1, {}), "errors_m": {"pixel": {"lidar": [None]}}}, ["b.json", "'errors_m.pixel'"]),
    ({"seed": 1, "holds": 8}, ["b.json", "nees_6dof"]),
    ({"seed": "1", "holds": 8, "nees_6dof": {}}, ["b.json", "'seed'", "'1'"]),
    ({"seed": 1, "holds": 8, "nees_6dof": {"pixels": {"lidar": [1.0]}}}, ["b.json", "'pixels'", "hold_bias"]),
    ({"seed": 1, "holds": 8, "nees_6dof": {"pixel": [1.0]}}, ["b.json", "'nees_6dof.pixel'", "list of numbers"]),
    ({"seed": 1, "holds": 8, "nees_6dof": {}, "nees_3dof": {"pixel": {"lidar": ["x"]}}},
     ["b.json", "'nees_3dof.pixel'"]),
    ({"seed": 1, "holds": 8, "nees_6dof": {}, "hold_sigma_floor": 0.001}, ["b.json", "'hold_sigma_floor'"]),
])
def test_runs_that_cannot_be_pooled_are_refused_naming_the_files(second, words):
    first = _run(0, {"pixel": {"lidar": [1.0]}})
    with pytest.raises(InputError) as exc:
        pool_mocap([("a.json", first), ("b.json", second)])
    for w in words:
        assert w in str(exc.value), (w, str(exc.value))


def test_the_same_seed_of_other_error_models_pools():
    # one file per model and seed, as the docs' runs were written
    a = _run(0, {"pixel": {"lidar": [1.0]}})
    b = _run(0, {"hold_bias": {"lidar": [1.0]}})
    assert set(pool_mocap([("a", a), ("b", b)])["models"]) == {"pixel", "hold_bias"}
    with pytest.raises(InputError, match="no runs"):
        pool_mocap([])
