"""Hostile names and paths (issue #22): a NUL in a manifest's path, sensor names that cannot name
a file (300 characters, a NUL, control characters), and a URDF whose joints form a cycle away
from the sensors' chain. Each is one error line naming the manifest or URDF and the field, at
load time - not a later error naming rigcal's hidden staging folder, not a copied cycle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory) -> Path:
    rng = np.random.default_rng(29)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
    return write_dataset(sim.dataset, tmp_path_factory.mktemp("names") / "data").parent


def _manifest(dataset_dir: Path, tmp_path: Path, old: str, new: str) -> Path:
    for p in dataset_dir.iterdir():
        (tmp_path / p.name).write_bytes(p.read_bytes())
    text = (dataset_dir / "rig.yaml").read_text()
    assert old in text, text
    (tmp_path / "rig.yaml").write_text(text.replace(old, new, 1))
    return tmp_path / "rig.yaml"


def _no_output(out: Path) -> None:
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]


@pytest.mark.parametrize("old, new, names", [
    # a NUL in a detections path (YAML's "\0" escape); was a traceback ("embedded null byte")
    ("detections: lidar1.csv", 'detections: "lidar\\0.csv"', ("rig.yaml: sensors[0].detections", "NUL byte")),
    # a 300-character name; was accepted, then an error naming the hidden staging folder
    ("name: lidar1", "name: " + "l" * 300, ("rig.yaml: sensors[0].name", "300 characters long", "at most 100")),
    ("name: lidar1", 'name: "lidar\\0one"', ("rig.yaml: sensors[0].name", "control characters")),
    ("name: lidar1", 'name: "lidar\\x1bone"', ("rig.yaml: sensors[0].name", "control characters", "\\x1b")),
])
def test_manifest_names_and_paths_are_refused_at_load(cli, refused, dataset_dir, tmp_path, old, new, names):
    manifest = _manifest(dataset_dir, tmp_path, old, new)
    if "name:" in old:  # the reference names the sensor too
        text = manifest.read_text().replace("reference: lidar1", "")
        manifest.write_text(text)
    out = tmp_path / "out"
    line = refused(cli("calibrate", manifest, "--out", out), *names, code=1)
    assert ".partial" not in line and "\x00" not in line
    _no_output(out)


def test_a_nul_in_an_ignore_path(cli, refused, dataset_dir, tmp_path):
    manifest = _manifest(dataset_dir, tmp_path, "sensors:", 'ignore: "ig\\0nore.yaml"\nsensors:')
    refused(cli("calibrate", manifest, "--out", tmp_path / "out"), "rig.yaml: ignore", "NUL byte", code=1)


URDF = """<robot name="r">
  <link name="base_link"/>
  <link name="lidar1"/>
  <link name="arm_a"/>
  <link name="arm_b"/>
  <link name="arm_c"/>
  <joint name="lidar_joint" type="fixed"><parent link="base_link"/><child link="lidar1"/></joint>
  <joint name="a_to_b" type="fixed"><parent link="arm_a"/><child link="arm_b"/></joint>
  <joint name="b_to_c" type="fixed"><parent link="arm_b"/><child link="arm_c"/></joint>
  <joint name="c_to_a" type="fixed"><parent link="arm_c"/><child link="arm_a"/></joint>
</robot>
"""

CALIBRATION = """parent_frame: base_link
reference: lidar1
sensors:
  lidar1:
    T_reference_sensor: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
"""


def test_a_joint_cycle_away_from_the_sensors_is_refused(cli, refused, tmp_path):
    """Was: accepted and copied into the output URDF."""
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(URDF)
    cal = tmp_path / "calibration.yaml"
    cal.write_text(CALIBRATION)
    out = tmp_path / "out.urdf"
    refused(cli("urdf", urdf, cal, "--out", out, "--body-link", "base_link"), "robot.urdf", "form a cycle",
            "'a_to_b', 'b_to_c', 'c_to_a'", code=1)
    assert not out.exists()
    assert urdf.read_text() == URDF


def test_parse_urdf_refuses_every_cycle():
    from rigcal.errors import InputError
    from rigcal.io.results.urdf import parse_urdf

    with pytest.raises(InputError, match=r"x\.urdf: line 8: joints 'a_to_b', 'b_to_c', 'c_to_a' form a cycle"):
        parse_urdf(URDF, "x.urdf")
    tree = URDF.replace('<child link="arm_a"/>', '<child link="arm_d"/>').replace(
        '<link name="arm_c"/>', '<link name="arm_c"/><link name="arm_d"/>')
    assert set(parse_urdf(tree, "x.urdf").joints) == {"lidar_joint", "a_to_b", "b_to_c", "c_to_a"}


@pytest.mark.parametrize("command", ["absolute", "mocap", "detect"])
def test_out_holding_an_input_is_refused_before_any_work(cli, refused, tmp_path, command):
    """Issue #22's "no input overwritten": a folder rigcal wrote (a dataset, a result) may be
    replaced by a new set of files - unless the run reads from it."""
    from rigcal.io.atomic import mark_output

    folder = tmp_path / "inputs"
    folder.mkdir()
    mark_output(folder)  # written by rigcal earlier
    for name in ("rig.yaml", "scan.ply", "labels.yaml", "mocap.yaml", "detect.yaml"):
        (folder / name).write_text("x: 1\n")
    argv = {"absolute": ["absolute", folder / "rig.yaml", "--external", "s", "--scan", folder / "scan.ply", "--labels",
                         folder / "labels.yaml"],
            "mocap": ["mocap", folder / "mocap.yaml"],
            "detect": ["detect", folder, "--rig", folder / "detect.yaml"]}[command]
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    refused(cli(*argv, "--out", folder), f"--out {folder}", "an input of this run", code=1)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
