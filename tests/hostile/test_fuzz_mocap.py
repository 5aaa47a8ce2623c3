"""Property-based fuzzing of the motion-capture parsers (pose CSV, target and optimizer JSON,
extrinsics JSON, the mocap YAML configuration): on any input each returns a value or raises a
RigcalError; never another exception, a hang or a memory blow-up (each run is limited)."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigcal.errors import RigcalError
from rigcal.geometry.se3 import from_rt
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.io.config.vicon_json import (
    optimizer_config_json_text,
    parse_optimizer_config,
    parse_vicon_target,
)
from rigcal.io.config.vicon_json import OptimizerConfig, vicon_target_json_text
from rigcal.mocap.config import parse_mocap_config
from rigcal.mocap.extrinsics import Extrinsics, extrinsics_json_text, parse_extrinsics_json
from rigcal.mocap.streams import parse_pose_csv
from rigcal.targets.templates import diamond_target

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True,
                    suppress_health_check=list(HealthCheck))

POSE_CSV = "t,x,y,z,qx,qy,qz,qw\n" + "".join(
    f"{0.01 * k:.2f},{1 + 0.001 * k},2,0.5,0,0,0.7071068,0.7071068\n" for k in range(8)
)
T = from_rt(matrix_from_rpy(np.radians([1.0, -2.0, 3.0])), [0.2, 0.0, 0.35])

CONFIG = """\
recording: run.bag
mocap:
  robot: {topic: /vicon/robot/robot}
  targets:
    diamond: {topic: /vicon/diamond/diamond, definition: target.json}
  max_gap_s: 0.04
initial_calibration: initial.json
robot_frame: base_link
sensors:
  - {name: lidar1, kind: lidar, topic: /velodyne_points, frame_id: velodyne_link, sigma_m: 0.01,
     elevation_fov_deg: [-15, 15], horizontal_step_deg: 0.4}
extraction: {max_linear_mps: 0.1, max_angular_dps: 5, motion_window_s: 0.5,
             sigma_translation_m: 0.03, sigma_rotation_deg: 5}
options: {loss: huber, target_pose_sigma: [0.0005, 0.00015]}
"""


def _ok_or_rigcal_error(fn, *args, **kwargs) -> None:
    try:
        fn(*args, **kwargs)
    except RigcalError:
        pass


def test_fuzz_pose_csv(limited, mutations):
    @SETTINGS
    @given(st.one_of(mutations(POSE_CSV), st.text(max_size=300)), st.sampled_from(["auto", "s", "ns"]))
    def fuzz(text, unit):
        _ok_or_rigcal_error(parse_pose_csv, text, "robot", "robot.csv", time_unit=unit)

    limited(fuzz, memory_mb=512, seconds=120)


def test_fuzz_target_and_optimizer_json(limited, mutations):
    target = vicon_target_json_text(diamond_target())
    optimizer = optimizer_config_json_text(OptimizerConfig())

    @SETTINGS
    @given(st.one_of(mutations(target), mutations(optimizer), st.text(max_size=200)))
    def fuzz(text):
        _ok_or_rigcal_error(parse_vicon_target, text, "target.json")
        _ok_or_rigcal_error(parse_optimizer_config, text, "optimizer.json")

    limited(fuzz, memory_mb=512, seconds=120)


def test_fuzz_extrinsics_json(limited, mutations):
    seed = extrinsics_json_text(Extrinsics({("base_link", "velodyne_link"): T}))

    @SETTINGS
    @given(st.one_of(mutations(seed), st.text(max_size=200)))
    def fuzz(text):
        _ok_or_rigcal_error(parse_extrinsics_json, text, "initial.json")

    limited(fuzz, memory_mb=512, seconds=120)


def test_fuzz_mocap_config(limited, mutations, tmp_path):
    (tmp_path / "run.bag").write_bytes(b"#ROSBAG V2.0\n")
    (tmp_path / "target.json").write_text(vicon_target_json_text(diamond_target()))
    (tmp_path / "initial.json").write_text(
        extrinsics_json_text(Extrinsics({("base_link", "velodyne_link"): T})))
    parse_mocap_config(CONFIG, str(tmp_path / "mocap.yaml"), tmp_path)  # the seed is valid

    @SETTINGS
    @given(st.one_of(mutations(CONFIG), st.text(max_size=200)))
    def fuzz(text):
        _ok_or_rigcal_error(parse_mocap_config, text, str(tmp_path / "mocap.yaml"), tmp_path)

    limited(fuzz, memory_mb=512, seconds=150)


def test_the_mutations_reach_the_parsers_checks():
    """The fuzzers are not vacuous: nasty numbers in a valid file are caught as errors."""
    bad = POSE_CSV.replace("1.001", "1.797e308", 1)
    try:
        parse_pose_csv(bad, "robot", "robot.csv")
    except RigcalError as exc:
        assert "robot.csv" in str(exc)
    else:
        raise AssertionError("a position of 1.797e308 m was accepted")
    assert json.loads(extrinsics_json_text(Extrinsics({("a", "b"): T})))
