"""rigcal's Python API (rigcal.api, exported lazily from the package)."""

from __future__ import annotations

import json
import subprocess
import sys
import typing

import numpy as np
import pytest

import rigcal
from rigcal import api
from rigcal.io.dataset.manifest import write_dataset
from rigcal.io.results.calibration_files import read_calibration_transforms
from rigcal.problem.calibrate import CalibrationOptions
from rigcal.problem.calibrate import calibrate as library_calibrate
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate


@pytest.fixture(scope="module")
def manifest(tmp_path_factory):
    rng = np.random.default_rng(3)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 10, min_fraction=1.0), rng=rng)
    return write_dataset(sim.dataset, tmp_path_factory.mktemp("api"))


def test_import_rigcal_loads_no_heavy_module():
    code = ("import sys, json, rigcal; "
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'numpy', 'scipy', 'cv2', 'matplotlib', 'rich', 'yaml', 'jinja2', 'rosbags'})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out) == []


def test_every_exported_name_resolves_and_is_listed():
    for name in rigcal.__all__:
        assert getattr(rigcal, name) is not None and name in dir(rigcal)
    assert rigcal.calibrate is api.calibrate and rigcal.load_dataset is api.load_dataset
    assert rigcal.CalibrationOptions is CalibrationOptions
    with pytest.raises(AttributeError, match="has no attribute 'calibrat'"):
        rigcal.calibrat  # noqa: B018


def test_the_functions_are_typed_and_documented():
    for name in ("load_dataset", "detect_board", "calibrate", "write_results", "write_urdf"):
        fn = getattr(rigcal, name)
        hints = typing.get_type_hints(fn, globalns=vars(api) | {
            "Dataset": rigcal.Dataset, "CalibrationResult": rigcal.CalibrationResult,
            "CalibrationOptions": CalibrationOptions,
            "DetectionRun": __import__("rigcal.detect.pipeline", fromlist=["x"]).DetectionRun,
            "WrittenUrdf": __import__("rigcal.io.results.urdf", fromlist=["x"]).WrittenUrdf})
        assert "return" in hints and len(fn.__doc__) > 200, name


def test_calibrate_is_the_library_calibration_with_the_options_asked(manifest):
    dataset = rigcal.load_dataset(manifest)
    ours = rigcal.calibrate(dataset, mode="pse", reference="camera1", detect_outliers=False)
    theirs = library_calibrate(dataset, CalibrationOptions(mode="pse", reference="camera1", detect_outliers=False))
    assert ours.reference == "camera1" and ours.mode == "pse"
    for name, est in theirs.sensors.items():
        np.testing.assert_array_equal(ours.sensors[name].T_reference_sensor, est.T_reference_sensor)
        np.testing.assert_array_equal(ours.sensors[name].covariance, est.covariance)
    base = CalibrationOptions(hold_radar_plane=True, reference="lidar1")
    held = rigcal.calibrate(dataset, mode="fcpe", options=base)
    assert held.reference == "lidar1" and held.sensors["radar1"].held  # the radar plane held


def test_calibrate_refuses_an_unknown_mode_or_option(manifest):
    dataset = rigcal.load_dataset(manifest)
    with pytest.raises(rigcal.InputError, match=r"mode must be one of mcpe, fcpe, pse, got 'xyz'"):
        rigcal.calibrate(dataset, mode="xyz")
    with pytest.raises(rigcal.InputError, match=r"unknown calibration option\(s\) \['fold'\]"):
        rigcal.calibrate(dataset, fold=2)


def test_write_urdf_from_a_result_equals_from_its_file(tmp_path, manifest):
    dataset = rigcal.load_dataset(manifest)
    result = rigcal.calibrate(dataset)
    paths = rigcal.write_results(result, tmp_path / "r")
    assert {p.name for p in paths} >= {"calibration.yaml", "calibration.launch"}
    assert not (tmp_path / "r" / "report.html").exists()  # no dataset given
    cal = read_calibration_transforms(tmp_path / "r" / "calibration.yaml")
    links = "".join(f'<link name="{f}"/>' for f in (cal.parent_frame, *cal.transforms))
    joints = "".join(f'<joint name="j_{f}" type="fixed"><parent link="base"/><child link="{f}"/>'
                     '<origin xyz="0 0 0" rpy="0 0 0"/></joint>' for f in (cal.parent_frame, *cal.transforms))
    (tmp_path / "in.urdf").write_text(f'<robot name="r"><link name="base"/>{links}{joints}</robot>')
    a = rigcal.write_urdf(result, tmp_path / "in.urdf", tmp_path / "a.urdf")
    b = rigcal.write_urdf(tmp_path / "r" / "calibration.yaml", tmp_path / "in.urdf", tmp_path / "b.urdf")
    assert a.skipped == b.skipped == () and (tmp_path / "a.urdf").read_text() == (tmp_path / "b.urdf").read_text()
    with pytest.raises(rigcal.InputError, match="is the input file"):
        rigcal.write_urdf(result, tmp_path / "in.urdf", tmp_path / "in.urdf")


def test_load_dataset_names_a_missing_manifest(tmp_path):
    with pytest.raises(rigcal.InputError, match=r"nothing\.yaml: manifest not found"):
        rigcal.load_dataset(tmp_path / "nothing.yaml")
