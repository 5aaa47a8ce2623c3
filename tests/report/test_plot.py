"""The calibration plot: a PNG of all detections in the reference frame."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.problem.result import STD_KEYS, CalibrationResult, SensorEstimate
from rigcal.report import plot_calibration
from rigcal.sim import make_rig_placements, move_boards, random_rig, simulate

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _truth_result(sim, reference: str, outliers: dict[str, tuple[int, ...]]) -> CalibrationResult:
    ds = sim.dataset
    sensors = {
        name: SensorEstimate(
            name=name,
            kind=ds.sensor(name).kind,
            frame_id=name,
            T_reference_sensor=sim.truth_T(reference, name),
            covariance=np.eye(6),
            std={k: 0.0 for k in STD_KEYS},
        )
        for name in ds.names
    }
    pairs = [f"{a}-{b}" for i, a in enumerate(ds.names) for b in ds.names[i + 1 :]]
    return CalibrationResult(
        mode="pse",
        reference=reference,
        converged=True,
        sensors=sensors,
        rmse_m={p: 0.01 + 0.001 * i for i, p in enumerate(pairs)},
        per_board_m={},
        outliers=outliers,
        num_boards=ds.num_boards,
    )


@pytest.fixture(scope="module")
def sim():
    rig = random_rig(5, n_lidar=1, n_camera=1, n_radar=1, n_radar3d=1)
    return simulate(rig, make_rig_placements(5, rig, 12), rng=5, reference="lidar1")


def test_writes_a_png(sim, tmp_path) -> None:
    ds = move_boards(sim.dataset, "camera1", [3], [0.4, 0.0, 0.0])
    result = _truth_result(sim, "lidar1", {"camera1": (3,)})
    out = plot_calibration(ds, result, tmp_path / "sub" / "calibration.png")
    assert out == tmp_path / "sub" / "calibration.png"
    data = out.read_bytes()
    assert data[:8] == PNG_MAGIC
    assert len(data) > 20_000
    # no temporary files are left beside it
    assert [p.name for p in out.parent.iterdir()] == ["calibration.png"]


def test_overwrites_and_handles_missing_estimates(sim, tmp_path) -> None:
    path = tmp_path / "plot.png"
    path.write_bytes(b"old")
    result = _truth_result(sim, "camera1", {})
    partial = CalibrationResult(
        **{**result.__dict__, "sensors": {k: v for k, v in result.sensors.items() if k != "radar1"}}
    )
    plot_calibration(sim.dataset, partial, str(path))
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_result_without_any_dataset_sensor_raises(sim, tmp_path) -> None:
    result = _truth_result(sim, "lidar1", {})
    empty = CalibrationResult(**{**result.__dict__, "sensors": {}})
    with pytest.raises(InputError, match="calibrates none of the dataset's sensors"):
        plot_calibration(sim.dataset, empty, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()
