"""The frame contract, end to end: one calibration (cameras with and without a separate optical
link in the robot's URDF), every writer run from the command line, every output read back by a
reader that is not rigcal's (an XML forward kinematics written here, launch files parsed, YAML,
JSON, urdfdom's check_urdf; and, where Debian's ROS 1 is installed, a real roscore with tf2
lookups) - all equal to 1e-9."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shlex
import shutil
import socket
import subprocess
import sys
import textwrap
import time
import types
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim import R_BODY_OPTICAL
from rigcal.sim.rig import SimSensor, make_rig_placements, prius_like_rig, simulate

TOL = 1e-9
# sensor -> frame_id: camera1 names a body-convention link with an optical child, camera2 names
# an optical link directly, camera3 a link with no optical child (it is the optical frame)
FRAMES = {"lidar1": "lidar_link", "camera1": "cam_front_link", "camera2": "cam_side_optical_frame",
          "camera3": "cam_roof", "radar1": "radar_link"}
# every frame a writer publishes -> the calibrated sensor it belongs to, and whether it is the
# sensor's measured frame (optical for cameras) or the body-convention link above it
PUBLISHED = {"cam_front_link": ("camera1", "link"), "cam_front_optical_frame": ("camera1", "measured"),
             "cam_side_link": ("camera2", "link"), "cam_side_optical_frame": ("camera2", "measured"),
             "cam_roof": ("camera3", "measured"), "radar_link": ("radar1", "measured")}
HALF_PI = "1.5707963267948966"


# ------------------------------------------------------------------------------ independent math
def rpy_matrix(r: float, p: float, y: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def quat_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    assert abs(n - 1.0) < 1e-12, n
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])


def homogeneous(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def inv(T: np.ndarray) -> np.ndarray:
    return homogeneous(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3])


def edges_to_poses(edges: dict[tuple[str, str], np.ndarray], root: str) -> dict[str, np.ndarray]:
    """Every frame's pose in ``root`` from (parent, child) -> T_parent_child edges, composed here
    (the frame may hang below ``root`` or beside it through a common ancestor)."""
    parent_of = {c: (p, T) for (p, c), T in edges.items()}

    def to_top(frame):
        T = np.eye(4)
        while frame in parent_of:
            p, T_pc = parent_of[frame]
            T, frame = T_pc @ T, p
        return frame, T

    top_root, T_top_root = to_top(root)
    out = {}
    for frame in set(parent_of) | {p for p, _ in edges}:
        top, T_top_frame = to_top(frame)
        if top == top_root:
            out[frame] = inv(T_top_root) @ T_top_frame
    return out


def urdf_edges(text: str) -> dict[tuple[str, str], np.ndarray]:
    """Fixed joints of a URDF as edges, with ElementTree and the rpy formula above."""
    root = ET.fromstring(text)
    out = {}
    for j in root.findall("joint"):
        if j.get("type") != "fixed":
            continue
        o = j.find("origin")
        xyz = [float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
        rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
        out[(j.find("parent").get("link"), j.find("child").get("link"))] = homogeneous(rpy_matrix(*rpy), xyz)
    return out


def ros1_launch_edges(text: str) -> dict[tuple[str, str], np.ndarray]:
    out = {}
    for node in ET.fromstring(text).findall("node"):
        assert (node.get("pkg"), node.get("type")) == ("tf2_ros", "static_transform_publisher")
        a = node.get("args").split()
        assert len(a) == 9  # x y z qx qy qz qw parent child (no period: /tf_static)
        v = [float(x) for x in a[:7]]
        out[(a[7], a[8])] = homogeneous(quat_matrix(*v[3:]), v[:3])
    return out


def _named(args: list[str]) -> tuple[tuple[str, str], np.ndarray]:
    d = dict(zip(args[::2], args[1::2]))
    T = homogeneous(quat_matrix(*(float(d[f"--q{k}"]) for k in "xyzw")),
                    [float(d[f"--{k}"]) for k in "xyz"])
    return (d["--frame-id"], d["--child-frame-id"]), T


def ros2_launch_edges(text: str, monkeypatch) -> dict[tuple[str, str], np.ndarray]:
    nodes = []
    launch = types.ModuleType("launch")
    launch.LaunchDescription = lambda entities: list(entities)
    actions = types.ModuleType("launch_ros.actions")
    actions.Node = lambda **kw: nodes.append(kw) or kw
    launch_ros = types.ModuleType("launch_ros")
    launch_ros.actions = actions
    for name, mod in (("launch", launch), ("launch_ros", launch_ros), ("launch_ros.actions", actions)):
        monkeypatch.setitem(sys.modules, name, mod)
    namespace: dict = {}
    exec(compile(text, "tf.launch.py", "exec"), namespace)
    namespace["generate_launch_description"]()
    return dict(_named(n["arguments"]) for n in nodes)


def ros2_run_edges(text: str) -> dict[tuple[str, str], np.ndarray]:
    out = {}
    for line in text.splitlines():
        words = shlex.split(line)
        assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
        key, T = _named(words[4:])
        out[key] = T
    return out


def document_edges(data: dict) -> dict[tuple[str, str], np.ndarray]:
    """A YAML/JSON export: every entry's 4x4, its xyz + rpy and its quaternion must agree."""
    out = {}
    for child, e in data["transforms"].items():
        T = np.array(e["T_parent_child"], dtype=float)
        assert np.abs(homogeneous(rpy_matrix(*e["rpy"]), e["xyz"]) - T).max() < TOL
        assert np.abs(homogeneous(quat_matrix(*e["quaternion_xyzw"]), e["xyz"]) - T).max() < TOL
        out[(e["parent"], child)] = T
    return out


# ------------------------------------------------------------------------------ the robot and rig
def _origin(T: np.ndarray) -> str:
    R = T[:3, :3]
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    roll, yaw = math.atan2(R[2, 1], R[2, 2]), math.atan2(R[1, 0], R[0, 0])
    return (f'<origin xyz="{" ".join(repr(float(v)) for v in T[:3, 3])}" '
            f'rpy="{repr(roll)} {repr(pitch)} {repr(yaw)}"/>')


def _joint(name, parent, child, T, kind="fixed") -> str:
    return (f'  <link name="{child}"/>\n  <joint name="{name}" type="{kind}">\n'
            f'    <parent link="{parent}"/><child link="{child}"/>\n    {_origin(T)}\n  </joint>\n')


def robot_urdf(T_base: dict[str, np.ndarray], with_radar: bool = True) -> str:
    """The robot as a ROS driver package would describe it: body-convention camera links with
    REP 103 optical children (one camera without), a lidar on a mount, a moving wheel."""
    opt = f'<origin xyz="0 0 0" rpy="-{HALF_PI} 0 -{HALF_PI}"/>'
    mount = homogeneous(np.eye(3), [1.0, 0.0, 1.5])
    body_of = lambda T: T @ homogeneous(R_BODY_OPTICAL.T, [0, 0, 0])  # noqa: E731
    text = '<?xml version="1.0"?>\n<robot name="car">\n  <link name="base_link"/>\n'
    text += _joint("lidar_mount_joint", "base_link", "lidar_mount", mount)
    text += _joint("lidar_joint", "lidar_mount", "lidar_link", inv(mount) @ T_base["lidar1"])
    text += _joint("cam_front_joint", "base_link", "cam_front_link", body_of(T_base["camera1"]))
    text += ('  <link name="cam_front_optical_frame"/>\n  <joint name="cam_front_optical_joint" '
             f'type="fixed">\n    <parent link="cam_front_link"/><child link="cam_front_optical_frame"/>\n'
             f"    {opt}\n  </joint>\n")
    text += _joint("cam_side_joint", "base_link", "cam_side_link", body_of(T_base["camera2"]))
    text += ('  <link name="cam_side_optical_frame"/>\n  <joint name="cam_side_optical_joint" '
             f'type="fixed">\n    <parent link="cam_side_link"/><child link="cam_side_optical_frame"/>\n'
             f"    {opt}\n  </joint>\n")
    text += _joint("cam_roof_joint", "base_link", "cam_roof", T_base["camera3"])
    if with_radar:
        text += _joint("radar_joint", "base_link", "radar_link", T_base["radar1"])
    text += _joint("wheel_joint", "base_link", "wheel_fl", homogeneous(np.eye(3), [2.7, 0.8, 0.3]),
                   "continuous").replace("</joint>", '  <axis xyz="0 1 0"/>\n  </joint>')
    return text + "</robot>\n"


def _nominal(T: np.ndarray, rng) -> np.ndarray:
    """A nominal mounting a few mm / tenths of a degree off the truth."""
    w = rng.normal(0, math.radians(0.3), 3)
    th = np.linalg.norm(w)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / th
    R = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K
    return homogeneous(T[:3, :3] @ R, T[:3, 3] + rng.normal(0, 0.005, 3))


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A simulated rig (lidar, three cameras, 2D radar) calibrated with `rigcal calibrate
    --initial robot.urdf`: the robot's URDF names every frame."""
    tmp = tmp_path_factory.mktemp("contract")
    rng = np.random.default_rng(19)
    base = {s.name: s for s in prius_like_rig()}
    cam = base["camera1"]
    side = homogeneous(rpy_matrix(0.0, 0.0, math.radians(-6)), [0.0, -0.45, 0.02]) @ cam.T_rig_sensor
    roof = homogeneous(rpy_matrix(0.0, math.radians(2), math.radians(4)), [-0.3, 0.2, 0.3]) @ cam.T_rig_sensor
    sensors = (base["lidar1"], cam, dataclasses.replace(cam, name="camera2", T_rig_sensor=side),
               dataclasses.replace(cam, name="camera3", T_rig_sensor=roof), base["radar1"])
    assert all(isinstance(s, SimSensor) for s in sensors)
    sim = simulate(sensors, make_rig_placements(rng, sensors, 14, min_fraction=1.0), rng=rng)
    dataset = dataclasses.replace(sim.dataset, sensors=tuple(
        dataclasses.replace(s, frame_id=FRAMES[s.name]) for s in sim.dataset.sensors))
    manifest = write_dataset(dataset, tmp / "data")
    nominal = {n: _nominal(sim.truth[n], rng) for n in FRAMES}
    (tmp / "robot.urdf").write_text(robot_urdf(nominal))
    (tmp / "robot_noradar.urdf").write_text(robot_urdf(nominal, with_radar=False))
    assert run(["calibrate", str(manifest), "--initial", str(tmp / "robot.urdf"),
                "--out", str(tmp / "res"), "--no-plot"]) == 0
    return tmp, sim


def _keep_nominal(N: np.ndarray, C: np.ndarray, directions) -> np.ndarray:
    """docs/urdf.md's rule for directions a calibration only bounds, written out here: in the
    nominal frame, the calibrated pose's z translation and Euler roll / pitch set to zero."""
    D = np.linalg.inv(N) @ C
    roll, pitch = math.atan2(D[2, 1], D[2, 2]), math.asin(-max(-1.0, min(1.0, D[2, 0])))
    R = rpy_matrix(roll, pitch, 0.0)
    yaw = math.atan2((D[:3, :3] @ R.T)[1, 0], (D[:3, :3] @ R.T)[0, 0])
    t = D[:3, 3].copy()
    if "z" in directions:
        t[2] = 0.0
    kept = rpy_matrix(0.0 if "roll" in directions else roll, 0.0 if "pitch" in directions else pitch, yaw)
    return N @ homogeneous(kept, t)


def _expected(tmp: Path, keep: bool = True) -> dict[str, np.ndarray]:
    """Every published frame's pose in lidar_link, from calibration.yaml's T_reference_sensor
    (measured frames) and REP 103's optical rotation - not from rigcal's frame module; with
    ``keep``, a sensor's bounded directions (the 2D radar's z, roll, pitch) at robot.urdf's
    values (docs/urdf.md)."""
    cal = yaml.safe_load((tmp / "res" / "calibration.yaml").read_text())
    T_ref = {n: np.array(e["T_reference_sensor"]) for n, e in cal["sensors"].items()}
    if keep:
        nominal = edges_to_poses(urdf_edges((tmp / "robot.urdf").read_text()), "lidar_link")
        for n, e in cal["sensors"].items():
            if e.get("bounded_offsets"):
                T_ref[n] = _keep_nominal(nominal[FRAMES[n]], T_ref[n], list(e["bounded_offsets"]))
    out = {}
    for frame, (sensor, role) in PUBLISHED.items():
        T = T_ref[sensor]
        out[frame] = T if role == "measured" else T @ homogeneous(R_BODY_OPTICAL.T, [0, 0, 0])
    return out


def _check(poses: dict[str, np.ndarray], expected: dict[str, np.ndarray], what: str,
           frames=None) -> None:
    for frame in frames or expected:
        assert frame in poses, f"{what}: frame '{frame}' is not published ({sorted(poses)})"
        err = np.abs(poses[frame] - expected[frame]).max()
        assert err < TOL, f"{what}: frame '{frame}' off by {err:.3g}"


def test_every_writer_publishes_the_same_transform_for_every_frame(calibrated, tmp_path,
                                                                  monkeypatch, capsys):
    tmp, _ = calibrated
    cal = tmp / "res" / "calibration.yaml"
    expected = _expected(tmp)
    read = {}
    # URDF out: our forward kinematics and the independent one
    assert run(["urdf", str(tmp / "robot.urdf"), str(cal), "--out", str(tmp_path / "cal.urdf")]) == 0
    urdf_text = (tmp_path / "cal.urdf").read_text()
    read["urdf (XML FK here)"] = edges_to_poses(urdf_edges(urdf_text), "lidar_link")
    from rigcal.io.results.urdf import forward_kinematics, parse_urdf

    parsed = parse_urdf(urdf_text, "cal.urdf")
    read["urdf (rigcal FK)"] = {f: forward_kinematics(parsed, "lidar_link", f) for f in expected}
    # exports with the URDF, and without it (calibration.yaml recorded the URDF's names)
    for urdf_args, tag in ((["--urdf", str(tmp / "robot.urdf")], "--urdf"), ([], "recorded")):
        files = {}
        for fmt, name in (("ros1-launch", "tf.launch"), ("ros2-launch", "tf.launch.py"),
                          ("ros2-run", "tf.sh"), ("yaml", "tf.yaml"), ("json", "tf.json")):
            files[fmt] = tmp_path / f"{tag}-{name}"
            assert run(["export", str(cal), "--format", fmt, "--out", str(files[fmt])] + urdf_args) == 0
        read[f"export ros1-launch {tag}"] = edges_to_poses(ros1_launch_edges(files["ros1-launch"].read_text()), "lidar_link")
        read[f"export ros2-launch {tag}"] = edges_to_poses(ros2_launch_edges(files["ros2-launch"].read_text(), monkeypatch), "lidar_link")
        read[f"export ros2-run {tag}"] = edges_to_poses(ros2_run_edges(files["ros2-run"].read_text()), "lidar_link")
        read[f"export yaml {tag}"] = edges_to_poses(document_edges(yaml.safe_load(files["yaml"].read_text())), "lidar_link")
        read[f"export json {tag}"] = edges_to_poses(document_edges(json.loads(files["json"].read_text())), "lidar_link")
    out = capsys.readouterr().out
    assert "warning" not in out  # the recorded names and the URDF agree: nothing to warn about
    # what `rigcal calibrate --initial robot.urdf` wrote itself
    read["calibration.launch"] = edges_to_poses(ros1_launch_edges((tmp / "res" / "calibration.launch").read_text()), "lidar_link")
    block = yaml.safe_load(cal.read_text())["frames"]
    assert block["urdf"] == str(tmp / "robot.urdf") and block["reference_frame"] == "lidar_link"
    read["calibration.yaml frames"] = edges_to_poses(document_edges(
        {"transforms": {e["child"]: e for e in block["static_transforms"]}}), "lidar_link")
    for what, poses in read.items():
        _check(poses, expected, what)
    # the original tool's per-sensor files name the measured frames
    for sensor, frame in (("camera1", "cam_front_optical_frame"), ("camera2", "cam_side_optical_frame"),
                          ("camera3", "cam_roof"), ("radar1", "radar_link")):
        doc = yaml.safe_load((tmp / "res" / f"{sensor}.yaml").read_text())
        assert (doc["target"], doc["source"]) == (frame, "lidar_link")
        _check({frame: inv(np.array(doc["transform"]))}, expected, f"{sensor}.yaml", [frame])
    # the URDF's optical joints are kept (REP 103), only the carrying joints moved
    joints = {j.get("name"): j for j in ET.fromstring(urdf_text).findall("joint")}
    assert joints["cam_front_optical_joint"].find("origin").get("rpy") == f"-{HALF_PI} 0 -{HALF_PI}"
    # urdfdom reads the written file as a valid tree (where installed)
    if shutil.which("check_urdf"):
        done = subprocess.run(["check_urdf", str(tmp_path / "cal.urdf")], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and "Successfully Parsed XML" in done.stdout, done.stdout + done.stderr


def test_a_frame_the_urdf_lacks_is_published_and_added_alike(calibrated, tmp_path, capsys):
    tmp, _ = calibrated
    cal = tmp / "res" / "calibration.yaml"
    expected = _expected(tmp, keep=False)  # no radar link to keep its bounded directions from
    urdf = tmp / "robot_noradar.urdf"
    assert run(["urdf", str(urdf), str(cal), "--add-missing", "--out", str(tmp_path / "add.urdf")]) == 0
    assert run(["export", str(cal), "--urdf", str(urdf), "--format", "ros1-launch",
                "--out", str(tmp_path / "tf.launch")]) == 0
    assert "added link 'radar_link'" in capsys.readouterr().out
    from_urdf = edges_to_poses(urdf_edges((tmp_path / "add.urdf").read_text()), "lidar_link")
    from_launch = edges_to_poses(ros1_launch_edges((tmp_path / "tf.launch").read_text()), "lidar_link")
    _check(from_urdf, expected, "urdf --add-missing")
    _check(from_launch, expected, "export --urdf (no radar link)")


def test_outputs_that_would_disagree_are_warned_about(calibrated, tmp_path, capsys):
    """A calibration.yaml written without the URDF publishes camera1's optical pose as
    'cam_front_link' (rule 2); `rigcal urdf` with the robot's URDF says so, and `rigcal export
    --urdf` gives the frames the URDF gets."""
    tmp, _ = calibrated
    data = yaml.safe_load((tmp / "res" / "calibration.yaml").read_text())
    del data["frames"]  # as written by calibrate without --initial robot.urdf
    plain = tmp_path / "calibration.yaml"
    plain.write_text(yaml.safe_dump(data))
    assert run(["export", str(plain), "--format", "ros1-launch", "--out", str(tmp_path / "a.launch")]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "camera 'camera1': frame 'cam_front_link' is published as the camera's optical frame" in out
    assert "camera 'camera2'" not in out  # its frame_id says optical
    assert run(["urdf", str(tmp / "robot.urdf"), str(plain), "--out", str(tmp_path / "u.urdf")]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "sensor 'camera1'" in out and "disagrees" in out and "--urdf" in out
    poses = edges_to_poses(ros1_launch_edges((tmp_path / "a.launch").read_text()), "lidar_link")
    wrong = poses["cam_front_link"][:3, :3].T @ _expected(tmp)["cam_front_link"][:3, :3]
    assert math.degrees(math.acos((np.trace(wrong) - 1) / 2)) == pytest.approx(120.0, abs=1e-6)


# ------------------------------------------------------------------------------ a real ROS 1
PYTHON3 = "/usr/bin/python3"
LOOKUP = textwrap.dedent("""
    import json, sys
    import rospy, tf2_ros
    root, frames = sys.argv[1], sys.argv[2:]
    rospy.init_node("rigcal_contract_lookup", anonymous=True, disable_signals=True)
    buf = tf2_ros.Buffer()
    listener = tf2_ros.TransformListener(buf)
    out = {}
    for f in frames:
        t = buf.lookup_transform(root, f, rospy.Time(0), rospy.Duration(20.0)).transform
        out[f] = [t.translation.x, t.translation.y, t.translation.z,
                  t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]
    print(json.dumps(out))
""")


def _ros_missing() -> str | None:
    for path in ("/usr/bin/roscore", "/usr/bin/roslaunch", "/usr/lib/tf2_ros/static_transform_publisher",
                 "/usr/lib/robot_state_publisher/robot_state_publisher", PYTHON3):
        if not os.path.exists(path):
            return f"Debian's ROS 1 is not installed ({path} missing; apt-get install ros-core tf2-tools ros-robot-state-publisher python3-tf2-ros)"
    probe = subprocess.run([PYTHON3, "-c", "import rospy, tf2_ros"], capture_output=True, timeout=60)
    if probe.returncode != 0:
        return "Debian's python3 cannot import rospy/tf2_ros"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Ros:
    """roscore on a free port, roslaunch files one after the other, tf2 lookups from Debian's
    python; every process started here is stopped by its process group id."""

    def __init__(self, tmp: Path):
        port = _free_port()
        self.env = {**os.environ, "ROS_MASTER_URI": f"http://127.0.0.1:{port}",
                    "ROS_HOME": str(tmp / "ros_home"), "ROS_LOG_DIR": str(tmp / "ros_log"),
                    "ROS_HOSTNAME": "127.0.0.1"}
        self.env.pop("PYTHONPATH", None)
        self.tmp = tmp
        self.procs: list[subprocess.Popen] = []
        self.core = self._start(["roscore", "-p", str(port)], "roscore.log")
        self._wait_master()

    def _start(self, argv, log) -> subprocess.Popen:
        p = subprocess.Popen(argv, env=self.env, stdout=open(self.tmp / log, "w"), stderr=subprocess.STDOUT,
                             stdin=subprocess.DEVNULL, start_new_session=True)
        self.procs.append(p)
        return p

    def _wait_master(self) -> None:
        probe = "import rosgraph, sys; sys.exit(0 if rosgraph.is_master_online() else 1)"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if subprocess.run([PYTHON3, "-c", probe], env=self.env, capture_output=True).returncode == 0:
                return
            time.sleep(0.5)
        raise AssertionError("roscore did not come up: " + (self.tmp / "roscore.log").read_text())

    def lookup(self, launch_file: Path, root: str, frames: list[str]) -> dict[str, np.ndarray]:
        p = self._start(["roslaunch", "--wait", str(launch_file)], launch_file.name + ".log")
        try:
            script = self.tmp / "lookup.py"
            script.write_text(LOOKUP)
            done = subprocess.run([PYTHON3, str(script), root, *frames], env=self.env,
                                  capture_output=True, text=True, timeout=120)
            assert done.returncode == 0, done.stderr + (self.tmp / (launch_file.name + ".log")).read_text()
            raw = json.loads(done.stdout.strip().splitlines()[-1])
        finally:
            self._stop(p)
        return {f: homogeneous(quat_matrix(*v[3:]), v[:3]) for f, v in raw.items()}

    def _stop(self, p: subprocess.Popen) -> None:
        if p.poll() is None:
            os.killpg(p.pid, 2)  # SIGINT: roslaunch shuts its nodes down
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, 9)
                p.wait(timeout=10)

    def close(self) -> None:
        for p in reversed(self.procs):
            self._stop(p)


@pytest.mark.slow
def test_a_real_roscore_publishes_what_the_files_say(calibrated, tmp_path):
    """tf2_ros static_transform_publisher from the written launch files, robot_state_publisher
    from the written URDF: tf2 lookups (float64 on /tf_static) equal the calibration to 1e-9."""
    reason = _ros_missing()
    if reason:
        pytest.skip(reason)
    tmp, _ = calibrated
    cal = tmp / "res" / "calibration.yaml"
    expected = _expected(tmp)
    assert run(["urdf", str(tmp / "robot.urdf"), str(cal), "--out", str(tmp_path / "cal.urdf")]) == 0
    assert run(["export", str(cal), "--urdf", str(tmp / "robot.urdf"), "--format", "ros1-launch",
                "--out", str(tmp_path / "export.launch")]) == 0
    rsp = tmp_path / "rsp.launch"
    rsp.write_text(f'<launch>\n  <param name="robot_description" textfile="{tmp_path / "cal.urdf"}"/>\n'
                   '  <node pkg="robot_state_publisher" type="robot_state_publisher" name="rsp"/>\n</launch>\n')
    ros = _Ros(tmp_path)
    try:
        frames = sorted(expected)
        for launch in (tmp / "res" / "calibration.launch", tmp_path / "export.launch", rsp):
            _check(ros.lookup(launch, "lidar_link", frames), expected, f"roscore + {launch.name}")
    finally:
        ros.close()
