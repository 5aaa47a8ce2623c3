"""``rigcal`` command line: parse -> run(args) -> int. Known errors become one line, exit 1.

Exit codes: 0 calibrated and consistent; 1 error (bad input, or the data cannot determine the
result); 2 command-line usage; 3 the result contradicts its own noise model (flagged by the
consistency check): nothing is written unless --force, which writes it with the verdict;
4 partial (``rigcal mocap``): the other sensors were calibrated and written, but at least one
sensor could not be and is reported as not calibrated with its reason (3 takes precedence).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path
from typing import Sequence

from rigcal import __version__
from rigcal.cli.args import count, number
from rigcal.errors import RigcalError

#: exit code of a result the consistency check flagged
EXIT_FLAGGED = 3
#: exit code of a partial result: some sensors calibrated (and written), others not (rigcal mocap)
EXIT_PARTIAL = 4

EPILOG_CALIBRATE = """examples:
  rigcal calibrate rig.yaml --mode fcpe --out results/
  rigcal calibrate rig.yaml --mode pse --reference lidar1 --out results/ --json
  rigcal calibrate --lidar lidar.csv --camera camera.csv --radar radar.csv --mode fcpe --out results/

exit codes: 0 consistent result written; 1 error; 2 usage; 3 the result contradicts its own
noise model (nothing written unless --force)
"""

EPILOG_DETECT = """examples:
  rigcal detect recording.bag --rig rig.yaml --out detections/
  rigcal detect rosbag2_dir/ --rig rig.yaml --out detections/ && rigcal calibrate detections/rig.yaml --out results/
"""

EPILOG_DEMO = """examples:
  rigcal demo --out demo_out/
  rigcal demo --mocap --out mocap_demo/ --seed 3
"""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rigcal",
        description="Joint extrinsic calibration of lidar, camera and radar rigs.",
    )
    p.add_argument("--version", action="version", version=f"rigcal {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    c = sub.add_parser(
        "calibrate",
        help="calibrate a rig from board detections",
        description="Calibrate every sensor of a rig into the reference sensor's frame from "
        "detections of the circle board (manifest rig.yaml, or the original tool's CSV/YAML "
        "files with --lidar/--camera/--radar).",
        epilog=EPILOG_CALIBRATE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    c.add_argument(
        "manifest", nargs="?",
        help="rig.yaml manifest (or a folder holding one); with --rig, a recording to detect first",
    )
    c.add_argument("--rig", metavar="RIG_YAML", help="detection rig: treat MANIFEST as a recording, detect, then calibrate")
    c.add_argument("--lidar", action="append", default=[], metavar="FILE", help="lidar detections (repeatable)")
    c.add_argument("--camera", action="append", default=[], metavar="FILE", help="camera detections (repeatable)")
    c.add_argument("--radar", action="append", default=[], metavar="FILE", help="2D radar detections (repeatable)")
    c.add_argument("--radar3d", action="append", default=[], metavar="FILE", help="3D radar detections (repeatable)")
    c.add_argument("--mode", default="fcpe", choices=["mcpe", "fcpe", "pse"], help="configuration (default fcpe)")
    c.add_argument("--reference", help="reference sensor name (default: manifest's, else first lidar)")
    c.add_argument("--out", required=True, metavar="DIR", help="output folder")
    c.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    c.add_argument("--ignore", metavar="FILE", help="original tool's ignore file (sensor -> CSV columns)")
    c.add_argument("--keep-outliers", action="store_true", help="do not search for bad detections")
    c.add_argument(
        "--hold-radar-plane",
        action="store_true",
        help="hold each 2D radar's z, roll and pitch at the initial guess",
    )
    c.add_argument("--initial", metavar="FILE", help="initial guesses: a previous calibration.yaml")
    c.add_argument("--cv-folds", type=count(0, 1000), default=5, metavar="N", help="leave-boards-out folds (0 = off)")
    c.add_argument("--no-plot", action="store_true", help="do not write calibration.png")
    c.add_argument(
        "--pse-noise", default="iterated", choices=["iterated", "identity"],
        help="PSE: per-sensor noise re-estimated until converged (default), or fixed at 1 "
        "(the original tool's variant)",
    )
    c.add_argument(
        "--force", action="store_true",
        help="write the result even when the consistency check flags it (exit code stays 3)",
    )

    t = sub.add_parser(
        "detect",
        help="detect the board in a recording (bag or folder) and write a dataset",
        description="Runs each sensor's board detector over a recording (ROS1 bag, ROS2 bag "
        "folder with sqlite3 or mcap storage, or a folder with one subfolder per sensor), finds "
        "the board placements automatically (stable periods matched across sensors) and writes "
        "rig.yaml + one CSV per sensor for `rigcal calibrate`.",
        epilog=EPILOG_DETECT,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    t.add_argument("recording", help="ROS1 .bag, ROS2 bag folder, or a folder of files")
    t.add_argument("--rig", required=True, metavar="RIG_YAML", help="sensors, topics and detector settings")
    t.add_argument("--out", required=True, metavar="DIR", help="output folder for rig.yaml + CSVs")

    a = sub.add_parser(
        "absolute",
        help="calibrate every sensor to the vehicle body with an external laser scan",
        description="Relates the rig to the body frame (Domhof et al. III-E): the external "
        "scanner is one more sensor of the board dataset (its detections of the placements it "
        "saw), so the joint calibration gives T_external_sensor for every rig sensor; wheel-rim "
        "labels (circle fits), single wheel-centre labels or markers in the external scan, plus "
        "the ground plane, give the body frame (origin below the rear axle centre, X forward, "
        "Y left, Z up); then T_body_sensor = T_body_external T_external_sensor. Writes "
        "absolute.yaml/.json and launch files.",
        epilog="example:\n  rigcal absolute rig.yaml --external leica --scan car_scan.pcd "
        "--labels wheels.yaml --out absolute/",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    a.add_argument("manifest", help="rig.yaml with the rig sensors AND the external scanner's detections")
    a.add_argument("--external", required=True, metavar="NAME", help="the external scanner's sensor name in the manifest")
    a.add_argument("--scan", required=True, metavar="CLOUD", help="external scan of the vehicle (PCD/PLY/NPY), external frame")
    a.add_argument("--labels", required=True, metavar="FILE", help="labels YAML/CSV: wheel rims/centres or markers")
    a.add_argument("--method", default="circle", choices=["circle", "single", "markers"])
    a.add_argument("--origin", default="rear_axle", choices=["rear_axle", "front_axle", "wheelbase_centre"])
    a.add_argument("--mode", default="fcpe", choices=["mcpe", "fcpe", "pse"])
    a.add_argument("--body-frame", default="base_link", help="name of the body frame (default base_link)")
    a.add_argument("--label-sigma-mm", type=number(0.0, 1e4), help="label noise, to include the body frame's uncertainty")
    a.add_argument(
        "--ground-check", action="append", default=[], metavar="SENSOR=CLOUD",
        help="a sensor's scan of flat ground: report the angle of its ground normal in the body frame (eq. 13)",
    )
    a.add_argument("--out", required=True, metavar="DIR")
    a.add_argument("--json", action="store_true", help="print absolute.json on stdout")
    a.add_argument(
        "--force", action="store_true",
        help="write the result even when the relative calibration's consistency check flags it (exit code stays 3)",
    )

    m = sub.add_parser(
        "mocap",
        help="calibrate lidars and cameras to the robot with a motion-capture system",
        description="Charron et al.: the motion-capture system tracks the robot and the targets; "
        "every sensor frame where a target is expected in view and standing still is cropped "
        "around it, the target is extracted (lidar: clustering + ICP of its template; camera: "
        "checkerboard corners or the cylinder's colour contour), and all sensors are calibrated "
        "to the robot frame in one problem - no overlap between sensors needed. Writes "
        "calibration.yaml (T_robot_sensor), extrinsics.json, diagnostics.csv (every measurement "
        "kept or rejected and why) and overlay images. The config format is in docs/mocap.md.",
        epilog="example:\n  rigcal mocap mocap.yaml --out mocap_out/\n\n"
        "exit codes: 0 consistent result written; 1 error (also when no sensor can be calibrated);\n"
        "2 usage; 3 the result contradicts its own noise model (nothing written unless --force);\n"
        "4 partial: the other sensors calibrated and written, some sensor not calibrated (each\n"
        "listed with its reason; in calibration.yaml and --json under not_calibrated)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    m.add_argument("config", metavar="CONFIG.yaml")
    m.add_argument("--out", required=True, metavar="DIR")
    m.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    m.add_argument("--max-overlays", type=count(0, 100000), default=None, metavar="N", help="overlay images per sensor")
    m.add_argument(
        "--force", action="store_true",
        help="write the result even when the consistency check flags it (exit code stays 3)",
    )

    st = sub.add_parser(
        "study",
        help="reproducible studies of the papers' experiments",
        description="Reproducible studies of the papers' simulated experiments.",
    )
    st_sub = st.add_subparsers(dest="study", metavar="STUDY")
    from rigcal.study.mocap_study import EPILOG as _STUDY_EPILOG
    from rigcal.study.mocap_study import add_arguments as _study_arguments

    _study_arguments(
        st_sub.add_parser(
            "mocap",
            help="Charron et al. Tables I-III: simulated motion-capture calibration",
            description="Reproduce Charron et al.'s simulated motion-capture calibration study "
            "(Tables I-III): simulated VLP-16 scans or camera images of the diamond or cylinder "
            "target, extraction, calibration from a perturbed start, many seeded trials; prints "
            "the table next to the paper's numbers.",
            epilog=_STUDY_EPILOG,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
    )

    u = sub.add_parser(
        "urdf",
        help="write calibrated sensor poses into a URDF",
        description="Sets the origin of the joint carrying each calibrated sensor's link so that "
        "the URDF's forward kinematics reproduce the calibration (fixed joints between the "
        "parent frame and the sensor are taken into account). Only the changed origin values "
        "differ from the input; a new file is written unless --in-place (then INPUT.bak is kept). "
        "CALIBRATION: a rigcal calibration.yaml / absolute.yaml, or the original tool's YAML "
        "{source, target, transform}.",
        epilog="examples:\n  rigcal urdf robot.urdf results/calibration.yaml --out robot_calibrated.urdf\n"
        "  rigcal urdf vehicle.urdf calibration.yaml --in-place",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    u.add_argument("urdf_in", metavar="INPUT.urdf")
    u.add_argument("calibration", metavar="CALIBRATION")
    out_group = u.add_mutually_exclusive_group(required=True)
    out_group.add_argument("--out", metavar="OUTPUT.urdf")
    out_group.add_argument("--in-place", action="store_true", help="overwrite INPUT.urdf (a backup is kept)")
    u.add_argument("--body-link", help="link the poses are relative to (default: the calibration's parent frame)")
    u.add_argument("--add-missing", action="store_true",
                   help="add a link on a fixed joint from the body link for every calibrated frame the "
                   "URDF lacks (default: skip it with a warning)")
    u.add_argument(
        "--joint", action="append", default=[], metavar="LINK=JOINT",
        help="update JOINT for the sensor LINK (default: the joint whose child is LINK)",
    )

    e = sub.add_parser(
        "export",
        help="export a calibration as static TF publishers (ROS1/ROS2) or YAML/JSON",
        description="Writes every calibrated transform as ROS1 static_transform_publisher nodes "
        "(x y z yaw pitch roll parent child), a ROS2 Python launch file, `ros2 run tf2_ros "
        "static_transform_publisher` lines, or YAML/JSON 4x4 matrices, at full precision.",
        epilog="examples:\n  rigcal export results/calibration.yaml --format ros2-launch --out calib.launch.py\n"
        "  rigcal export absolute.yaml --format ros2-run",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    e.add_argument("calibration", metavar="CALIBRATION")
    e.add_argument("--format", required=True, choices=["ros1-launch", "ros2-launch", "ros2-run", "yaml", "json"])
    e.add_argument("--out", metavar="FILE", help="output file (default: stdout)")

    d = sub.add_parser(
        "demo",
        help="simulate a Prius-like rig, calibrate with all modes, compare with the truth",
        description="Simulates raw data of a lidar (HDL-64E-like scans), a stereo camera "
        "(rendered 1936x1216 pairs) and a 2D radar (detection lists with clutter) on a car while "
        "a board is held at 12 placements, writes it as a real ROS bag, detects the board, finds "
        "the placements automatically, calibrates with MCPE, FCPE and PSE and prints the errors "
        "against the simulated truth. Needs no files; about 1-2 minutes. --detections-only "
        "skips the raw data (seconds). --mocap instead simulates a motion-capture (Vicon) "
        "session of a lidar and two cameras with no shared view, writes it as a ROS bag with "
        "mocap.yaml, runs the `rigcal mocap` pipeline on it and compares every sensor's "
        "calibration to the robot frame with the truth (seconds).",
        epilog=EPILOG_DEMO,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    d.add_argument("--out", default="demo_out", metavar="DIR", help="output folder (default demo_out)")
    d.add_argument("--seed", type=int, default=7, help="random seed (default 7)")
    d.add_argument("--boards", type=int, default=None,
                   help="board placements (default 12 raw, 29 detections-only)")
    d.add_argument("--detections-only", action="store_true", help="simulate detections directly (fast, no raw data)")
    d.add_argument("--mocap", action="store_true",
                   help="motion-capture demo: a lidar and two cameras with no shared view calibrated to the robot frame")
    d.add_argument("--holds", type=int, default=None, metavar="N",
                   help="--mocap: target poses held in each sensor's view (default 4)")
    d.add_argument("--bag-format", default=None, choices=["rosbag1", "rosbag2-sqlite3", "rosbag2-mcap"],
                   help="bag format of the raw demo (default rosbag1)")
    d.add_argument("--full-rate", action="store_true", help="simulate lidar and stereo at 10 Hz (slow)")
    d.add_argument("--keep-bag", action="store_true", help="keep the simulated bag in the output folder")
    return p


def _progress_bar(console, eta: bool = False):
    """The progress bar every long command shows (transient when not on a terminal)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    columns = ["[progress.description]{task.description}", BarColumn(), MofNCompleteColumn()]
    if eta:
        columns.append(TimeRemainingColumn())
    return Progress(*columns, console=console, transient=not console.is_terminal)


def _stage_progress(bar):
    """A ``progress(stage, done, total)`` callback that gives every stage its own bar row."""
    tasks: dict[str, int] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=None)
        bar.update(tasks[stage], completed=done, total=total or None)

    return progress


def _pose_table(title: str, estimates, rpy_std_decimals: int = 2):
    """A table of sensor poses (x y z, roll pitch yaw) with their standard deviations."""
    from rich.table import Table

    t = Table(title=title)
    for col in ("sensor", "x (m)", "y (m)", "z (m)", "roll", "pitch", "yaw (deg)", "std xyz (mm)", "std rpy (deg)"):
        t.add_column(col, justify="right" if col != "sensor" else "left")
    for name, est in estimates.items():
        x, y, z = est.xyz_m
        r, p, yw = est.rpy_deg
        s = est.std
        bounded = getattr(est, "bounded", {}) or {}

        def cell(key: str, text: str) -> str:
            # a direction bounded only by a constraint has no meaningful std
            return "bnd" if key.split("_")[0] in bounded else text

        t.add_row(
            name,
            f"{x:.4f}", f"{y:.4f}", f"{z:.4f}", f"{r:.3f}", f"{p:.3f}", f"{yw:.3f}",
            "/".join(cell(k, f"{s[k] * 1000:.1f}") for k in ("x_m", "y_m", "z_m")),
            "/".join(cell(k, f"{s[k]:.{rpy_std_decimals}f}") for k in ("roll_deg", "pitch_deg", "yaw_deg")),
        )
    return t


def _verdict_lines(result, console) -> None:
    """The consistency verdict, first thing on the terminal."""
    v = getattr(result, "verdict", None)
    if v is None:
        return
    if v.status == "flagged":
        console.print("[bold red]FLAGGED[/bold red]: the result contradicts its own noise model")
        for c in v.failed:
            console.print(f"  [red]{c.name}[/red]: {c.detail}")
    else:
        console.print("[bold green]consistent[/bold green]: every check agrees with the noise model")
    for c in v.checks:
        if c.status == "note":
            console.print(f"  note ({c.name}): {c.detail}")


def _not_written(console, what: str = "the result") -> int:
    """Say that a flagged result was not written; the exit code for it."""
    console.print(
        f"[bold red]not written[/bold red]: {what} failed its consistency check "
        f"(exit code {EXIT_FLAGGED}); --force writes it anyway, with the verdict"
    )
    return EXIT_FLAGGED


def _summary(result, console, verdict_first: bool = True) -> None:
    from rich.table import Table

    if verdict_first:
        _verdict_lines(result, console)
    t = _pose_table(f"{result.mode.upper()} - reference {result.reference}", result.sensors)
    console.print(t)
    e = Table(title="errors between sensors")
    for col in ("pair", "RMSE (mm)", "cross-val RMSE (mm)", "worst board"):
        e.add_column(col)
    for pair, v in result.rmse_m.items():
        cv = result.cross_validation_rmse_m.get(pair)
        per = result.per_board_m.get(pair, {})
        worst = max(per.items(), key=lambda kv: kv[1]) if per else None
        e.add_row(
            pair,
            f"{v * 1000:.2f}",
            "-" if cv is None else f"{cv * 1000:.2f}",
            "-" if worst is None else f"#{worst[0]}: {worst[1] * 1000:.1f} mm",
        )
    for pair, v in result.reprojection_px.items():
        e.add_row(pair, f"{v:.3f} px (reprojection)", "-", "-")
    console.print(e)
    if result.outliers:
        console.print("outliers (excluded): " + "; ".join(f"{s}: boards {list(b)}" for s, b in result.outliers.items()))
    else:
        console.print("outliers (excluded): none")
    if result.noise_sigma_m:
        console.print(
            "PSE noise std (mm): "
            + "; ".join(f"{s}: {'/'.join(f'{v * 1000:.2f}' for v in sig)}" for s, sig in result.noise_sigma_m.items())
        )
    for w in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {w}")


def _cmd_calibrate(args, console) -> int:
    from rigcal.errors import InputError
    from rigcal.io.calibration_files import read_initial_poses
    from rigcal.io.ignore import read_ignore_file
    from rigcal.io.manifest import dataset_from_files, load_manifest
    from rigcal.io.atomic import staged_folder
    from rigcal.io.results import result_to_json_text, write_results
    from rigcal.problem.calibrate import CalibrationOptions, calibrate

    files = args.lidar or args.camera or args.radar or args.radar3d
    if args.manifest and files:
        raise InputError("give either a manifest or --lidar/--camera/--radar files, not both")
    if args.rig:
        if not args.manifest or files:
            raise InputError("--rig needs a recording as the positional argument (and no --lidar/--camera/--radar)")
        dataset = _detect(args.manifest, args.rig, console).dataset
    elif args.manifest:
        dataset = load_manifest(args.manifest)
    elif files:
        dataset = dataset_from_files(
            lidar=args.lidar, camera=args.camera, radar=args.radar, radar3d=args.radar3d
        )
    else:
        raise InputError("no input: give a rig.yaml manifest or --lidar/--camera/--radar files")
    if args.ignore:
        dataset = dataset.with_excluded(read_ignore_file(args.ignore, dataset))
    options = CalibrationOptions(
        mode=args.mode,
        reference=args.reference,
        detect_outliers=not args.keep_outliers,
        hold_radar_plane=args.hold_radar_plane,
        initial=read_initial_poses(args.initial) if args.initial else None,
        cross_validation_folds=args.cv_folds,
        pse_noise=args.pse_noise,
    )
    result = calibrate(dataset, options)
    if result.flagged and not args.force:
        _summary(result, console)
        return _not_written(console)
    with staged_folder(args.out) as stage:
        write_results(result, stage)
        if not args.no_plot:
            from rigcal.report.plot import plot_calibration

            plot_calibration(dataset, result, stage / "calibration.png")
    if args.json:
        sys.stdout.write(result_to_json_text(result) + "\n")
    _summary(result, console)
    console.print(f"results written to {args.out}/" + (" (FLAGGED, written with --force)" if result.flagged else ""))
    return EXIT_FLAGGED if result.flagged else 0


def _detect(recording_path: str, rig_path: str, console):
    from rich.table import Table

    from rigcal.detect.pipeline import run_detection
    from rigcal.io.folder import open_any
    from rigcal.io.rig_config import load_rig_config

    rig = load_rig_config(rig_path)
    with open_any(recording_path) as rec, _progress_bar(console, eta=True) as bar:
        task = bar.add_task("detecting", total=None)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        run = run_detection(rec, rig, progress=progress)
    table = Table(title=f"detection over {recording_path}")
    for col in ("sensor", "frames", "detections", "rejections (reason: count)", "placements"):
        table.add_column(col)
    for name, st in run.stats.items():
        fails = ", ".join(f"{k}: {v}" for k, v in sorted(st.failures.items(), key=lambda kv: -kv[1])) or "-"
        table.add_row(name, str(st.frames), str(st.detections), fails, f"{st.placements}/{len(run.placements)}")
    console.print(table)
    console.print(f"{len(run.placements)} board placements found")
    return run


def _cmd_detect(args, console) -> int:
    from rigcal.io.atomic import staged_folder
    from rigcal.io.manifest import write_dataset

    run = _detect(args.recording, args.rig, console)
    with staged_folder(args.out) as stage:
        name = write_dataset(run.dataset, stage).name
    console.print(f"dataset written to {Path(args.out) / name}")
    return 0


def _cmd_absolute(args, console) -> int:
    import math

    from rigcal.absolute.evaluate import ground_normal_angle
    from rigcal.absolute.labels import parse_labels_csv, parse_labels_yaml
    from rigcal.absolute.pipeline import absolute_calibration
    from rigcal.errors import InputError
    from rigcal.io._text import read_text
    from rigcal.io.absolute_io import absolute_to_json_text, write_absolute
    from rigcal.io.atomic import staged_folder
    from rigcal.io.manifest import load_manifest
    from rigcal.io.pointcloud import read_point_cloud

    dataset = load_manifest(args.manifest)
    text = read_text(args.labels, "labels file")
    labels = (parse_labels_csv if args.labels.lower().endswith(".csv") else parse_labels_yaml)(text, args.labels)
    scan = read_point_cloud(args.scan, sensor=args.external).points_xyz
    checks = []
    for item in args.ground_check:
        if "=" not in item:
            raise InputError(f"--ground-check {item!r}: expected SENSOR=CLOUD")
        name, path = item.split("=", 1)
        dataset.sensor(name)  # names the sensors if unknown
        checks.append((name, read_point_cloud(path, sensor=name).points_xyz))
    result = absolute_calibration(
        dataset, args.external, labels, scan, args.method, args.origin, args.mode,
        body_frame=args.body_frame,
        label_sigma_m=None if args.label_sigma_mm is None else args.label_sigma_mm / 1000.0,
    )
    ground = {name: ground_normal_angle(pts, result.T_body_sensor(name)) for name, pts in checks}
    _verdict_lines(result.relative, console)
    if result.relative.flagged and not args.force:
        return _not_written(console, "the relative calibration")
    with staged_folder(args.out) as stage:
        write_absolute(result, stage)
    if args.json:
        sys.stdout.write(absolute_to_json_text(result) + "\n")
    b = result.body
    console.print(
        f"body frame '{result.body_frame}' ({args.origin}) from {args.method} labels: wheelbase "
        f"{b.wheelbase_m:.4f} m, tracks {b.track_rear_m:.4f} / {b.track_front_m:.4f} m, ground rms "
        f"{b.ground.rms_m * 1000:.1f} mm"
    )
    table = _pose_table(
        f"T_body_sensor (body frame {result.body_frame})", result.sensors, rpy_std_decimals=3
    )
    console.print(table)
    for name, g in ground.items():
        console.print(f"ground check {name}: normal {math.degrees(g.angle_rad):.3f} deg from body Z")
    for w in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {w}")
    console.print(f"written to {args.out}/ (absolute.yaml, absolute.json, launch files)")
    return EXIT_FLAGGED if result.relative.flagged else 0


def _cmd_mocap(args, console) -> int:
    from rich.table import Table

    from rigcal.io.atomic import staged_folder
    from rigcal.io.results import result_to_json_text
    from rigcal.mocap.config import load_mocap_config
    from rigcal.mocap.pipeline import SUMMARY_COLUMNS, run_mocap, summary_rows, write_mocap_outputs

    config = load_mocap_config(args.config)
    with _progress_bar(console) as bar:
        task = bar.add_task("extracting", total=None)
        run = run_mocap(config, progress=lambda d, t: bar.update(task, completed=d, total=t))

    def not_calibrated() -> None:
        from rich.markup import escape

        for name, why in run.not_calibrated.items():
            console.print(f"[bold yellow]not calibrated[/bold yellow]: {escape(name)}: {escape(why)}",
                          soft_wrap=True)

    if run.result.flagged and not args.force:
        _summary(run.result, console)
        not_calibrated()
        return _not_written(console)
    with staged_folder(args.out) as stage:
        write_mocap_outputs(run, stage, max_overlays=args.max_overlays)
    if args.json:
        sys.stdout.write(result_to_json_text(run.result) + "\n")
    _verdict_lines(run.result, console)
    table = Table(title="measurements per sensor")
    for col in SUMMARY_COLUMNS:
        table.add_column(col)
    for row in summary_rows(run):
        table.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row))
    console.print(table)
    _summary(run.result, console, verdict_first=False)
    not_calibrated()
    notes = []
    if run.result.flagged:
        notes.append("FLAGGED, written with --force")
    if run.not_calibrated:
        notes.append(f"partial: {len(run.not_calibrated)} of {len(config.sensors)} sensors not calibrated "
                     f"({', '.join(run.not_calibrated)}), exit code {EXIT_PARTIAL}")
    console.print(f"results written to {args.out}/" + (f" ({'; '.join(notes)})" if notes else ""))
    if run.result.flagged:
        return EXIT_FLAGGED
    return EXIT_PARTIAL if run.not_calibrated else 0


def _cmd_urdf(args, console) -> int:
    from rigcal.errors import InputError
    from rigcal.io.calibration_files import read_calibration_transforms
    from rigcal.io.urdf import write_urdf

    cal = read_calibration_transforms(args.calibration)
    joint_for = {}
    for item in args.joint:
        if "=" not in item:
            raise InputError(f"--joint {item!r}: expected LINK=JOINT")
        link, joint = item.split("=", 1)
        joint_for[link] = joint
    written = write_urdf(
        args.urdf_in,
        args.urdf_in if args.in_place else args.out,
        dict(cal.transforms),
        args.body_link or cal.parent_frame,
        in_place=args.in_place,
        joint_for=joint_for or None,
        kinds=cal.kinds,
        missing="add" if args.add_missing else "skip",
    )
    done = [f for f in cal.transforms if f not in written.skipped and f not in written.added]
    console.print(
        f"updated {len(done)} sensor link(s) ({', '.join(done) or 'none'}) relative to "
        f"'{args.body_link or cal.parent_frame}' -> {written.path}"
        + (f" (backup {written.backup})" if written.backup else "")
    )
    for frame in written.added:
        console.print(f"added link '{frame}' on a fixed joint from '{args.body_link or cal.parent_frame}'")
    for note in written.notes:
        console.print(f"note: {note}")
    for frame in written.skipped:
        console.print(
            f"[yellow]warning:[/yellow] no link '{frame}' in {args.urdf_in}: skipped (set the "
            "sensor's frame_id to its URDF link, or --add-missing)"
        )
    return 0


def _same_path(a: str, b: str) -> bool:
    """True when paths ``a`` and ``b`` name the same file (or would, once created)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _cmd_export(args, console) -> int:
    from rigcal.errors import InputError
    from rigcal.io import tf_export
    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.calibration_files import read_calibration_transforms

    if args.out and _same_path(args.out, args.calibration):
        raise InputError(
            f"--out {args.out}: is the input calibration file; choose another output path"
        )
    cal = read_calibration_transforms(args.calibration)
    t, parent = dict(cal.transforms), cal.parent_frame
    text = {
        "ros1-launch": lambda: tf_export.ros1_launch_text(t, parent),
        "ros2-launch": lambda: tf_export.ros2_launch_py_text(t, parent),
        "ros2-run": lambda: "\n".join(tf_export.ros2_run_commands(t, parent)) + "\n",
        "yaml": lambda: tf_export.yaml_text(t, parent),
        "json": lambda: tf_export.json_text(t, parent),
    }[args.format]()
    if args.out:
        atomic_write_text(args.out, text)
        console.print(f"{len(t)} transform(s) from '{parent}' written to {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def _print_demo(report, console) -> None:
    from rich.table import Table

    console.print(report.description)
    table = Table(title="errors against the simulated truth (T_reference_sensor)")
    for col in (
        "mode", "sensor", "translation (mm)", "rotation (deg)",
        "2D radar: in-plane (mm) / yaw (deg)", "2D radar: z (mm) / tilt (deg)", "RMSE pairs (mm)",
    ):
        table.add_column(col)
    for o in report.outcomes:
        rm = ", ".join(f"{k} {v * 1000:.1f}" for k, v in o.result.rmse_m.items())
        for i, (name, e) in enumerate(o.errors.items()):
            radar2d = o.result.sensors[name].kind.value == "radar"
            table.add_row(
                o.mode.upper() if i == 0 else "",
                name,
                f"{e.translation_m * 1000:.1f}",
                f"{e.rotation_deg:.3f}",
                f"{e.in_plane_m * 1000:.1f} / {e.yaw_deg:.3f}" if radar2d else "",
                f"{e.out_of_plane_m * 1000:.1f} / {e.tilt_deg:.2f}" if radar2d else "",
                rm if i == 0 else "",
            )
        for w in o.result.warnings:
            console.print(f"[yellow]{o.mode.upper()} warning:[/yellow] {w}")
    console.print(table)
    for n in report.notes:
        console.print(n)
    if any(s.kind.value == "radar" for o in report.outcomes[:1] for s in o.result.sensors.values()):
        console.print(
            "A 2D radar measures range and azimuth only: its in-plane pose is determined, its "
            "z and tilt only through the elevation limit (see the warnings)."
        )
    console.print(f"outputs written to {report.out_dir}/")


def _print_mocap_demo(report, console) -> None:
    from rich.table import Table

    console.print(report.description)
    _verdict_lines(report.run.result, console)
    table = Table(title="T_robot_sensor against the simulated truth")
    for col in ("sensor", "model", "initial error mm / deg", "final error mm / deg",
                "reported std mm / deg", "frames", "kept", "rejected"):
        table.add_column(col, justify="left" if col in ("sensor", "model") else "right")
    for o in report.sensors:
        table.add_row(
            o.sensor, f"{o.model} {o.kind}",
            f"{o.initial_error.translation_m * 1000:.1f} / {o.initial_error.rotation_deg:.2f}",
            f"{o.final_error.translation_m * 1000:.2f} / {o.final_error.rotation_deg:.4f}",
            f"{o.std_m * 1000:.2f} / {o.std_deg:.4f}",
            str(o.frames), str(o.kept), str(o.rejected),
        )
    console.print(table)
    for o in report.sensors:
        console.print(f"{o.sensor} rejections: " + (", ".join(f"{k} {v}" for k, v in o.rejections.items()) or "none"))
    console.print(
        "std: root sum of squares of the per-axis standard deviations the calibration reports: "
        "from each sensor's own noise and a per-hold error of the target pose shared by the "
        "frames of a hold; on this simulated session, whose motion capture is exact, it is "
        "conservative (it assumes at least 0.5 mrad / 0.25 mm per hold)"
    )
    console.print(f"scene (run.bag, mocap.yaml, target, intrinsics, initial.json) written to {report.scene_dir}/")
    console.print(f"calibration (calibration.yaml, extrinsics.json, diagnostics.csv, overlays/) written to {report.results_dir}/")
    console.print(f"run it again with: rigcal mocap {report.scene_dir / 'mocap.yaml'} --out {report.results_dir}")


def _cmd_demo(args, console) -> int:
    from rigcal.demo import detections_demo, mocap_demo, raw_demo
    from rigcal.errors import InputError
    from rigcal.io.atomic import staged_folder

    if args.mocap:
        others = [flag for flag, given in (
            ("--detections-only", args.detections_only), ("--boards", args.boards is not None),
            ("--bag-format", args.bag_format is not None), ("--full-rate", args.full_rate),
            ("--keep-bag", args.keep_bag)) if given]
        if others:
            raise InputError(f"--mocap does not take {', '.join(others)} (it takes --out, --seed and --holds)")
    elif args.holds is not None:
        raise InputError("--holds applies only to the motion-capture demo (--mocap)")
    out = Path(args.out)
    # the whole demo folder is written as one set: a new folder beside --out, renamed at the end
    with staged_folder(out) as stage:
        if args.mocap:
            with _progress_bar(console) as bar:
                report = mocap_demo(stage, seed=args.seed, holds=4 if args.holds is None else args.holds,
                                    progress=_stage_progress(bar))
        elif args.detections_only:
            report = detections_demo(stage, seed=args.seed, boards=29 if args.boards is None else args.boards)
        else:
            with _progress_bar(console) as bar:
                report = raw_demo(
                    stage, seed=args.seed, boards=12 if args.boards is None else args.boards,
                    bag_format=args.bag_format or "rosbag1", full_rate=args.full_rate,
                    keep_bag=args.keep_bag, progress=_stage_progress(bar),
                )
    report = _moved(report, stage, out)
    (_print_mocap_demo if args.mocap else _print_demo)(report, console)
    return 0


def _moved(report, stage: Path, out: Path):
    """``report`` with the paths inside the staging folder shown where they are now (``out``)."""
    import dataclasses

    def move(value):
        if isinstance(value, Path) and value.is_relative_to(stage):
            return out / value.relative_to(stage)
        if isinstance(value, str):
            return value.replace(str(stage), str(out))
        if isinstance(value, tuple) and all(isinstance(v, (str, Path)) for v in value):
            return tuple(move(v) for v in value)
        return value

    return dataclasses.replace(report, **{
        f.name: move(getattr(report, f.name)) for f in dataclasses.fields(report)
    })


EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)
EXIT_TERMINATED = 143  # SIGTERM (128 + SIGTERM)


class Terminated(BaseException):
    """Raised in the main thread when the process receives SIGTERM (see :func:`entry`)."""


def _dispatch(args, parser, console) -> int:
    if args.command == "calibrate":
        return _cmd_calibrate(args, console)
    if args.command == "detect":
        return _cmd_detect(args, console)
    if args.command == "absolute":
        return _cmd_absolute(args, console)
    if args.command == "mocap":
        return _cmd_mocap(args, console)
    if args.command == "study":
        if args.study != "mocap":
            parser.parse_args(["study", "--help"])
        from rigcal.study.mocap_study import run as run_study

        text, code = run_study(args)
        (sys.stdout if code == 0 else sys.stderr).write(text + "\n")
        return code
    if args.command == "urdf":
        return _cmd_urdf(args, console)
    if args.command == "export":
        return _cmd_export(args, console)
    if args.command == "demo":
        return _cmd_demo(args, console)
    return 2


def run(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code.

    A :class:`RigcalError` is one line on stderr and exit code 1; Ctrl-C and SIGTERM print
    "interrupted" and return 130 / 143 (outputs are written as whole sets, so nothing
    half-written is left). numpy's floating-point RuntimeWarnings are not shown (each result
    carries its own checks); with ``-v`` an unexpected internal error shows its traceback.
    """
    import warnings

    parser = _parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    if args.command is None:
        parser.print_help()
        return 2
    try:
        from rich.console import Console

        if getattr(args, "out", None):  # refuse an unusable --out before any work
            from rigcal.io.limits import path_stat

            path_stat(args.out, "--out")

        # with --json, stdout carries only the JSON; the human summary goes to stderr
        to_err = bool(getattr(args, "json", False))
        stream = sys.stderr if to_err else sys.stdout
        console = Console(stderr=to_err, highlight=False, width=None if stream.isatty() else 130)
        with warnings.catch_warnings():
            if not args.verbose:
                warnings.simplefilter("ignore", RuntimeWarning)
            return _dispatch(args, parser, console)
    except RigcalError as exc:
        sys.stderr.write(f"rigcal: error: {exc}\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write("\nrigcal: interrupted (nothing half-written is left)\n")
        return EXIT_INTERRUPTED
    except Terminated:
        sys.stderr.write("rigcal: terminated (nothing half-written is left)\n")
        return EXIT_TERMINATED
    except MemoryError:
        sys.stderr.write(f"rigcal: error: out of memory in '{args.command}' (an input too large?)\n")
        return 1
    except RecursionError:
        sys.stderr.write(f"rigcal: error: input nested too deeply for '{args.command}'\n")
        return 1


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def entry() -> None:
    import signal

    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        code = run()
    except KeyboardInterrupt:  # Ctrl-C while the arguments were parsed
        sys.stderr.write("\nrigcal: interrupted\n")
        code = EXIT_INTERRUPTED
    except Terminated:
        code = EXIT_TERMINATED
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
