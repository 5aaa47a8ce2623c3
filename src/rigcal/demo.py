"""Built-in demonstrations with simulated ground truth (what ``rigcal demo`` runs).

* :func:`detections_demo` - a Prius-like rig simulated at the detection level, calibrated with
  MCPE, FCPE and PSE;
* :func:`raw_demo` - raw sensor data (lidar scans, stereo images, radar detections) simulated
  into a real ROS bag, detected, calibrated, compared with the truth;
* :func:`mocap_demo` - a motion-capture calibration session of a lidar and two cameras with no
  shared view (:mod:`rigcal.sim.mocap_scene`), calibrated to the robot frame by the same code
  as ``rigcal mocap``, compared with the truth.

They return values; printing is the CLI's job.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

import numpy as np

from rigcal.errors import ConvergenceError, InputError
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.compare import PoseError, errors_against_truth
from rigcal.problem.result import CalibrationResult

if TYPE_CHECKING:  # heavy imports stay in the functions that need them
    from rigcal.mocap.pipeline import MocapRun
    from rigcal.sim.mocap_scene import MocapScene


@dataclass(frozen=True)
class ModeOutcome:
    mode: str
    result: CalibrationResult
    errors: Mapping[str, PoseError]


@dataclass(frozen=True)
class DemoReport:
    description: str
    outcomes: tuple[ModeOutcome, ...]
    out_dir: Path
    detection_stats: Mapping[str, object] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def _calibrate_all(dataset, truth, out: Path, modes=("mcpe", "fcpe", "pse"),
                   raw_images=None, progress=None) -> tuple[ModeOutcome, ...]:
    """Calibrate with every mode and write each result set; ``raw_images(result)``, when given,
    returns the report's lidar-on-image overlays from the recording. calibration.png too when
    matplotlib is installed (the ``plots`` extra)."""
    from rigcal.extras import available
    from rigcal.io.results.report import write_calibration_set

    plot = available("matplotlib")
    outcomes = []
    if progress:
        progress(0, len(modes))
    for mode in modes:
        result = calibrate(dataset, CalibrationOptions(mode=mode, cross_validation_folds=5))
        write_calibration_set(result, dataset, out / mode, raw_images(result) if raw_images else None)
        if plot:
            from rigcal.report.plot import plot_calibration

            plot_calibration(dataset, result, out / mode / "calibration.png")
        outcomes.append(ModeOutcome(mode, result, errors_against_truth(result, truth)))
        if progress:
            progress(len(outcomes), len(modes))
    return tuple(outcomes)


MIN_DEMO_BOARDS, MAX_DEMO_BOARDS = 3, 200


def _check_boards(boards: int) -> None:
    if isinstance(boards, bool) or not isinstance(boards, int) or not (
        MIN_DEMO_BOARDS <= boards <= MAX_DEMO_BOARDS
    ):
        raise InputError(
            f"--boards {boards}: expected {MIN_DEMO_BOARDS} to {MAX_DEMO_BOARDS} board placements "
            f"(fewer than {MIN_DEMO_BOARDS} cannot determine a pose)"
        )


def detections_demo(out_dir: str | os.PathLike[str], seed: int = 7, boards: int = 29) -> DemoReport:
    """Simulate detections of a Prius-like rig, calibrate with every mode, compare with truth."""
    _check_boards(boards)
    from rigcal.io.dataset.manifest import write_dataset
    from rigcal.sim import make_rig_placements, prius_like_rig, simulate

    rng = np.random.default_rng(seed)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, boards), rng=rng, reference=sensors[0].name)
    out = Path(out_dir)
    write_dataset(sim.dataset, out / "dataset")
    return DemoReport(
        description=(
            f"simulated detections of {len(sensors)} sensors ({', '.join(s.name for s in sensors)}), "
            f"{boards} board placements, seed {seed}"
        ),
        outcomes=_calibrate_all(sim.dataset, sim.truth, out),
        out_dir=out,
    )


RAW_TOPICS = {
    "lidar1": "/lidar/points",
    "camera1": ("/stereo/left/image_rect", "/stereo/right/image_rect"),
    "radar1": "/radar/targets",
}


def demo_raw_rig(full_rate: bool = False):
    """The raw Prius-like rig of :func:`rigcal.sim.raw.prius_like_raw_rig` with a 0.24 m stereo
    baseline (enough disparity for boards at 7 m). By default at demo rates: lidar 2 Hz, stereo
    1.5 Hz (rendering and matching 1936 x 1216 pairs dominates); ``full_rate``: 10 Hz."""
    from rigcal.sim.raw import StereoCamera, prius_like_raw_rig

    out = []
    for s in prius_like_raw_rig():
        if s.name == "camera1":
            s = dataclasses.replace(s, model=StereoCamera(s.model.camera, 0.24))
            if not full_rate:
                s = dataclasses.replace(s, rate_hz=1.5)
        elif s.name == "lidar1" and not full_rate:
            s = dataclasses.replace(s, rate_hz=2.0)
        out.append(s)
    return tuple(out)


def raw_rig_yaml(sensors) -> str:
    """The detection rig configuration matching :func:`demo_raw_rig`'s topics."""
    cam = next(s for s in sensors if s.name == "camera1").model
    c = cam.camera
    return f"""# detection rig of the simulated Prius-like recording
sensors:
  - {{name: lidar1, kind: lidar, topic: {RAW_TOPICS['lidar1']}}}
  - name: camera1
    kind: camera
    input: stereo_pair
    topic: {RAW_TOPICS['camera1'][0]}
    right_topic: {RAW_TOPICS['camera1'][1]}
    stereo: {{fx: {c.fx}, fy: {c.fy}, cx: {c.cx}, cy: {c.cy}, baseline_m: {cam.baseline_m}}}
  - name: radar1
    kind: radar
    topic: {RAW_TOPICS['radar1']}
    elevation_fov_deg: 9
    detector: {{rcs_min_dbsm: 5, range_max_m: 15}}
reference: lidar1
"""


def frames_by_topic(frames) -> dict[str, list]:
    """Simulated frames (lidar clouds, stereo pairs, radar lists) grouped by bag topic."""
    from rigcal.recording import ImageFrame, StereoFrame

    out: dict[str, list] = {}
    for f in frames:
        if isinstance(f, StereoFrame):
            left, right = RAW_TOPICS["camera1"]
            out.setdefault(left, []).append(ImageFrame(f.sensor, f.t_ns, f.left))
            out.setdefault(right, []).append(ImageFrame(f.sensor, f.t_ns, f.right))
        else:
            out.setdefault(RAW_TOPICS[f.sensor], []).append(f)
    return out


def detection_errors(run, recording) -> dict[str, np.ndarray]:
    """Per sensor, the distance [m] of each placement's averaged detection from the truth."""
    from rigcal.dataset import SensorKind
    from rigcal.geometry.se3 import invert
    from rigcal.sensors.radar import project_2d
    from rigcal.targets.circle_board import board_centres, reflector_in_board

    board = recording.board
    out: dict[str, list[float]] = {}
    for pl in run.placements:
        k = recording.timeline.placement_at((pl.start_ns + pl.end_ns) // 2)
        if k < 0:
            continue
        T_rig_board = recording.T_rig_board[k]
        for name, period in pl.periods.items():
            T_s_b = invert(recording.truth[name]) @ T_rig_board
            kind = next(s for s in recording.sensors if s.name == name).sensor_kind
            if kind.is_point_cloud:
                truth = board_centres(board) @ T_s_b[:3, :3].T + T_s_b[:3, 3]
                err = np.linalg.norm(period.points - truth, axis=1)
            else:
                refl = T_s_b[:3, :3] @ reflector_in_board(board) + T_s_b[:3, 3]
                truth = project_2d(refl[None])[0] if kind == SensorKind.RADAR else refl
                err = np.atleast_1d(np.linalg.norm(period.points - truth))
            out.setdefault(name, []).extend(float(e) for e in err)
    return {k: np.array(v) for k, v in out.items()}


def _size_bytes(path: Path) -> int:
    """Size of a file, or of every file under a folder (a ROS2 bag)."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def raw_demo(
    out_dir: str | os.PathLike[str],
    seed: int = 7,
    boards: int = 12,
    bag_format: str = "rosbag1",
    full_rate: bool = False,
    keep_bag: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
) -> DemoReport:
    """Simulate raw data of a Prius-like rig into a real bag, detect the board in it, find the
    placements automatically, calibrate with every mode and compare with the truth."""
    _check_boards(boards)
    from rigcal.detect.pipeline import run_detection
    from rigcal.io.recordings.bag import write_recording
    from rigcal.report.raw import raw_overlays
    from rigcal.io.recordings.open_any import open_any
    from rigcal.io.dataset.manifest import write_dataset
    from rigcal.io.config.rig_config import parse_rig_config
    from rigcal.sim.raw import raw_rig_placements, simulate_recording

    rng = np.random.default_rng(seed)
    sensors = demo_raw_rig(full_rate)
    placements = raw_rig_placements(rng, sensors, boards)
    from rigcal.stages import StageClock

    clock = StageClock()
    rec = simulate_recording(sensors, placements, rng, dwell_s=2.5, transition_s=1.5,
                             progress=(lambda d, t: progress("simulating raw data", d, t)) if progress else None)
    clock.lap(f"simulating {len(rec.frames)} frames of {len(sensors)} sensors, {boards} placements")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rig_text = raw_rig_yaml(sensors)
    (out / "detect_rig.yaml").write_text(rig_text)
    rig = parse_rig_config(rig_text, str(out / "detect_rig.yaml"), out)
    with tempfile.TemporaryDirectory(dir=out if keep_bag else None) as tmp:
        name = "recording.bag" if bag_format == "rosbag1" else "recording"
        bag_dir = out if keep_bag else Path(tmp)
        if progress:
            progress(f"writing the {bag_format} bag", 0, 1)
        bag = write_recording(bag_dir / name, frames_by_topic(rec.frames), bag_format)
        if progress:
            progress(f"writing the {bag_format} bag", 1, 1)
        clock.lap(f"writing the {bag_format} bag")
        with open_any(bag) as recording:
            run = run_detection(
                recording, rig, progress=(lambda d, t: progress("detecting", d, t)) if progress else None
            )
            write_dataset(run.dataset, out / "dataset")
            clock.lap(f"detecting the board: {len(run.placements)} placements")
            # calibrated while the bag is still there: each report shows the lidar on the images
            outcomes = _calibrate_all(run.dataset, rec.truth, out, raw_images=lambda result: raw_overlays(
                recording, rig, run.placements, run.dataset, result),
                progress=(lambda d, t: progress("calibrating MCPE, FCPE, PSE", d, t)) if progress else None)
            clock.lap("calibrating with every mode and writing the reports")
        bag_mb = _size_bytes(bag) / 1e6
    det_err = detection_errors(run, rec)
    notes = [
        f"{len(run.placements)} board placements found automatically ({boards} simulated)",
        "detection error vs truth (median / max, mm): "
        + ", ".join(f"{k} {np.median(v) * 1000:.1f} / {np.max(v) * 1000:.1f}" for k, v in det_err.items()),
    ]
    if keep_bag:
        notes.append(f"bag kept at {bag} ({bag_mb:.0f} MB)")
    else:
        notes.append(f"the simulated {bag_format} bag ({bag_mb:.0f} MB) was deleted after detection; "
                     "--keep-bag keeps it in the output folder")
    return DemoReport(
        description=(
            f"simulated raw data ({', '.join(f'{s.name}: {type(s.model).__name__}' for s in sensors)}), "
            f"{boards} placements, seed {seed}; written as {bag_format}, detected, calibrated"
        ),
        outcomes=outcomes,
        out_dir=out,
        detection_stats=run.stats,
        notes=tuple(notes),
    )


# --------------------------------------------------------------------------------------------
# motion capture


@dataclass(frozen=True)
class MocapSensorOutcome:
    """One sensor of :func:`mocap_demo`: its kind and camera / lidar model, the initial and the
    final calibration's error against the simulated truth (``T_robot_sensor``), the reported
    1-sigma uncertainty (root sum of squares of the x, y, z [m] and roll, pitch, yaw [deg]
    standard deviations), and its frames, kept and rejected measurements (rejections by
    reason)."""

    sensor: str
    kind: str
    model: str
    initial_error: PoseError
    final_error: PoseError
    std_m: float
    std_deg: float
    frames: int
    kept: int
    rejected: int
    rejections: Mapping[str, int]


@dataclass(frozen=True)
class MocapDemoReport:
    """What :func:`mocap_demo` did: the scene it wrote, the pipeline's run, one outcome per
    sensor, and where the scene (``scene_dir``) and the calibration outputs (``results_dir``,
    the files in ``written``) went."""

    description: str
    scene: MocapScene
    run: MocapRun
    sensors: tuple[MocapSensorOutcome, ...]
    scene_dir: Path
    results_dir: Path
    written: tuple[Path, ...]


def _rss(std: Mapping[str, float], keys: tuple[str, ...]) -> float:
    return float(np.sqrt(sum(float(std[k]) ** 2 for k in keys)))


#: fewest holds of the flat target per sensor that determine the demo lidar's pose
MIN_MOCAP_DEMO_HOLDS = 3
#: the demo's MCS noise per sample of each body (translation [m], rotation [rad]): a Vicon's
DEMO_MCS_NOISE = (0.00015, 0.0003)


def mocap_demo(
    out_dir: str | os.PathLike[str],
    seed: int = 7,
    holds: int = 4,
    progress: Callable[[str, int, int], None] | None = None,
    shown_as: str | os.PathLike[str] | None = None,
) -> MocapDemoReport:
    """Write a simulated motion-capture session of :func:`rigcal.sim.mocap_scene.default_rig`
    (a forward lidar, a left pinhole camera and a right radtan camera, no shared view; the
    target held ``holds`` times in each sensor's view) to ``out_dir/scene``, run it through the
    ``rigcal mocap`` path (:func:`~rigcal.mocap.config.load_mocap_config` ->
    :func:`~rigcal.mocap.pipeline.run_mocap` -> :func:`~rigcal.mocap.pipeline.write_mocap_outputs`
    into ``out_dir/results``) and compare every sensor's initial and final calibration with
    the truth. ``progress(stage, done, total)`` reports the simulation and the extraction.
    ``shown_as``: the folder ``out_dir`` will be published as (the CLI stages the demo in a
    hidden folder and renames it): the outputs name the scene's files where the user finds
    them, not in the staging folder."""
    from rigcal.mocap.config import load_mocap_config
    from rigcal.mocap.pipeline import KEPT, run_mocap, write_mocap_outputs
    from rigcal.problem.compare import pose_error
    from rigcal.sim.mocap_scene import write_mocap_scene

    if isinstance(holds, int) and not isinstance(holds, bool) and 1 <= holds < MIN_MOCAP_DEMO_HOLDS:
        raise InputError(
            f"--holds {holds}: the demo's lidar measures every point of the flat diamond, and "
            f"{holds} plate pose(s) leave its pose undetermined (two planes leave a translation "
            f"along their intersection free); give at least {MIN_MOCAP_DEMO_HOLDS}"
        )
    out = Path(out_dir)

    def stage(name: str):
        if progress is None:
            return None
        return lambda done, total: progress(name, done, total)

    scene = write_mocap_scene(out / "scene", seed=seed, holds=holds, progress=stage("simulating the session"),
                              mcs_noise=DEMO_MCS_NOISE)
    run = run_mocap(load_mocap_config(scene.config_path), progress=stage("extracting targets"))
    if run.not_calibrated:  # the simulated session shows every sensor: a partial run is a failure
        raise ConvergenceError("mocap demo: " + "; ".join(
            f"sensor '{n}' not calibrated: {why}" for n, why in run.not_calibrated.items()))
    if shown_as is not None:  # a rejection's detail names the bag it read
        there = str(Path(shown_as).absolute())

        def shown(text: str) -> str:
            for here in {str(out.resolve()), str(out.absolute())}:
                text = text.replace(here, there)
            return text

        run = dataclasses.replace(run, diagnostics=tuple(
            dataclasses.replace(d, detail=shown(d.detail)) for d in run.diagnostics))
    written = write_mocap_outputs(run, out / "results")
    counts = run.counts
    outcomes = []
    for s in scene.sensors:
        est = run.result.sensors[s.name]
        c = counts.get(s.name, {})
        rejections = {k: v for k, v in sorted(c.items(), key=lambda kv: -kv[1]) if k != KEPT}
        outcomes.append(MocapSensorOutcome(
            sensor=s.name,
            kind=s.kind,
            model=s.model.name,
            initial_error=pose_error(run.initial[s.name], scene.truth[s.name]),
            final_error=pose_error(run.final[s.name], scene.truth[s.name]),
            std_m=_rss(est.std, ("x_m", "y_m", "z_m")),
            std_deg=_rss(est.std, ("roll_deg", "pitch_deg", "yaw_deg")),
            frames=int(run.frames.get(s.name, 0)),
            kept=int(c.get(KEPT, 0)),
            rejected=int(sum(rejections.values())),
            rejections=rejections,
        ))
    span_s = (scene.end_ns - scene.t0_ns) / 1e9
    return MocapDemoReport(
        description=(
            f"simulated motion-capture session, seed {scene.seed}: "
            + ", ".join(f"{o.sensor} ({o.model} {o.kind})" for o in outcomes)
            + f" with no shared view; a diamond held {holds} times in each sensor's view, "
            f"{span_s:.1f} s with frames at {scene.timing.sensor_hz} Hz and Vicon poses at "
            f"{scene.timing.mcs_hz} Hz ({1000 * DEMO_MCS_NOISE[0]:.2f} mm / "
            f"{1000 * DEMO_MCS_NOISE[1]:.1f} mrad noise per sample, a dropout); lidar range noise "
            f"{1000 * scene.sensors[0].model.range_sigma_m:.0f} mm; initial calibration off by up "
            f"to 3 cm and 5 deg per axis"
        ),
        scene=scene,
        run=run,
        sensors=tuple(outcomes),
        scene_dir=scene.folder,
        results_dir=out / "results",
        written=tuple(written),
    )


# --------------------------------------------------------------------------------------------
# absolute calibration: rig -> vehicle body, then into the robot's URDF


@dataclass(frozen=True)
class AbsoluteDemoReport:
    """What :func:`absolute_demo` did: the scene it wrote (``scene_dir``: dataset with the
    external scanner, ``scan.pcd``, ``wheels.yaml``, ``vehicle.urdf``), the body-frame result
    and its errors against the simulated truth, and the calibrated URDF."""

    description: str
    result: object  # rigcal.absolute.result.AbsoluteResult
    errors: Mapping[str, PoseError]
    scene_dir: Path
    results_dir: Path
    urdf_path: Path
    command: str


def _nominal_urdf(vehicle, names: Sequence[str], rng: np.random.Generator) -> str:
    """A URDF of the vehicle with one link per sensor, placed where a tape measure would put
    it (the truth off by a few cm and degrees), for the calibration to correct."""
    from rigcal.geometry.se3 import from_rt
    from rigcal.geometry.so3 import matrix_from_rpy
    from rigcal.io.results.urdf import format_float, origin_from_matrix

    parts = ['<?xml version="1.0"?>', '<robot name="demo_vehicle">', '  <link name="base_link"/>']
    for name in names:
        T = vehicle.T_body_sensor(name) @ from_rt(
            matrix_from_rpy(np.radians(rng.uniform(-2.0, 2.0, 3))), rng.uniform(-0.03, 0.03, 3))
        xyz, rpy = origin_from_matrix(T)
        parts += [
            f'  <link name="{name}"/>',
            f'  <joint name="{name}_joint" type="fixed">',
            '    <parent link="base_link"/>',
            f'    <child link="{name}"/>',
            f'    <origin xyz="{" ".join(map(format_float, xyz))}" rpy="{" ".join(map(format_float, rpy))}"/>',
            "  </joint>",
        ]
    return "\n".join(parts + ["</robot>", ""])


def absolute_demo(
    out_dir: str | os.PathLike[str],
    seed: int = 7,
    boards: int = 20,
    progress: Callable[[str, int, int], None] | None = None,
) -> AbsoluteDemoReport:
    """Simulate an absolute calibration (Domhof et al., Sec. V): the Prius-like rig on a car,
    ``boards`` placements seen by the rig and by an external scanner (a P40-like lidar, 2 mm),
    the scanner's scan of the car and 10 clicked rim points per wheel (2 mm). Writes them as
    the files ``rigcal absolute`` reads (``out_dir/scene``), runs that path (manifest, labels,
    PCD in; ``out_dir/absolute`` out), puts the result into the scene's URDF
    (``out_dir/vehicle_calibrated.urdf``) and compares ``T_body_sensor`` with the truth."""
    from rigcal.absolute.labels import format_labels_yaml, parse_labels_yaml
    from rigcal.absolute.pipeline import absolute_calibration
    from rigcal.dataset import SensorKind
    from rigcal.io.results.absolute import write_absolute
    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.results.calibration_files import read_calibration_transforms
    from rigcal.io.dataset.manifest import load_manifest, write_dataset
    from rigcal.io.clouds import read_point_cloud, write_pcd
    from rigcal.io.results.urdf import write_urdf
    from rigcal.problem.compare import pose_error
    from rigcal.recording import PointCloudFrame
    from rigcal.sim.rig import SimSensor, make_rig_placements, simulate
    from rigcal.sim.vehicle import ExternalScanner, SimVehicle, simulate_external_scan, simulate_rim_labels

    _check_boards(boards)
    rng = np.random.default_rng(seed)
    vehicle, scanner = SimVehicle(), ExternalScanner()
    external = SimSensor(
        "leica", SensorKind.LIDAR, scanner.T_body_stations[0], sigma_m=0.002,
        max_azimuth_deg=180.0, max_elevation_deg=60.0, min_elevation_deg=-60.0, max_range_m=30.0,
    )
    if progress:
        progress("simulating boards, scan and labels", 0, 3)
    sim = simulate(vehicle.sensors + (external,), make_rig_placements(rng, vehicle.sensors, boards), rng=rng)
    if progress:
        progress("simulating boards, scan and labels", 1, 3)
    scan = simulate_external_scan(vehicle, scanner, rng=rng)
    if progress:
        progress("simulating boards, scan and labels", 2, 3)
    labels = simulate_rim_labels(vehicle, scan.T_external_body, rng, n_points=10, sigma_m=0.002)
    if progress:
        progress("simulating boards, scan and labels", 3, 3)
    out = Path(out_dir)
    scene = out / "scene"
    names = [s.name for s in vehicle.sensors]
    manifest = write_dataset(sim.dataset, scene / "dataset")
    write_pcd(scene / "scan.pcd", PointCloudFrame("leica", 0, scan.points_external), data="binary")
    atomic_write_text(scene / "wheels.yaml", format_labels_yaml(labels))
    atomic_write_text(scene / "vehicle.urdf", _nominal_urdf(vehicle, names, rng))
    # the `rigcal absolute` path: every input read back from the files just written
    result = absolute_calibration(
        load_manifest(manifest), "leica",
        parse_labels_yaml((scene / "wheels.yaml").read_text(), str(scene / "wheels.yaml")),
        read_point_cloud(scene / "scan.pcd", sensor="leica").points_xyz,
    )
    results = out / "absolute"
    write_absolute(result, results)
    from rigcal.io.results.report import write_report
    from rigcal.report.data import absolute_report

    write_report(absolute_report(result, load_manifest(manifest)), results)
    cal = read_calibration_transforms(results / "absolute.yaml")
    urdf = write_urdf(scene / "vehicle.urdf", out / "vehicle_calibrated.urdf", dict(cal.transforms),
                      cal.parent_frame, kinds=cal.kinds, missing="skip")
    errors = {n: pose_error(result.sensors[n].T_body_sensor, vehicle.T_body_sensor(n)) for n in names}
    return AbsoluteDemoReport(
        description=(
            f"simulated absolute calibration, seed {seed}: {', '.join(names)} on a car "
            f"(wheelbase {vehicle.wheelbase_m} m), {boards} board placements also seen by an "
            "external scanner (2 mm), its scan of the car and 10 clicked rim points per wheel"
        ),
        result=result,
        errors=errors,
        scene_dir=scene,
        results_dir=results,
        urdf_path=urdf.path,
        command=(
            f"rigcal absolute {manifest} --external leica --scan {scene / 'scan.pcd'} "
            f"--labels {scene / 'wheels.yaml'} --out {results}"
        ),
    )
