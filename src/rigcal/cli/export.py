"""``rigcal export``: a calibration as static TF publishers (ROS1/ROS2), YAML/JSON or a Kalibr
camchain."""

from __future__ import annotations

import os
import sys

from rigcal.cli import export_mcap
from rigcal.cli.args import subcommand

FORMATS = ("ros1-launch", "ros2-launch", "ros2-run", "yaml", "json", "kalibr", "mcap")


def add_parser(sub) -> None:
    e = subcommand(
        sub, "export",
        help="export a calibration as static TF publishers (ROS1/ROS2), YAML/JSON, a Kalibr camchain "
        "or a Foxglove scene",
        description="Writes every calibrated transform as ROS1 tf2_ros static_transform_publisher "
        "nodes (x y z qx qy qz qw parent child, on /tf_static), a ROS2 Python launch file, `ros2 "
        "run tf2_ros static_transform_publisher` lines, or YAML/JSON (4x4, xyz, rpy, quaternion), "
        "at full precision; the calibration's cameras as a Kalibr camchain (--format kalibr, "
        "intrinsics from --intrinsics or --rig); or an MCAP scene for Foxglove with the frame tree, "
        "the board detections and the residuals (--format mcap). Frames follow one contract "
        "(docs/conventions.md): a camera's calibrated frame is its optical frame; with --urdf the "
        "robot's links name the frames exactly as `rigcal urdf` writes them (a camera link with a "
        "separate optical child is published with that child).",
        epilog="examples:\n  rigcal export results/calibration.yaml --format ros2-launch --out calib.launch.py\n"
        "  rigcal export results/calibration.yaml --urdf robot.urdf --format ros1-launch --out calib.launch\n"
        "  rigcal export absolute.yaml --format ros2-run\n"
        "  rigcal export results/calibration.yaml --format kalibr --rig detect_rig.yaml --out camchain.yaml\n"
        "  rigcal export results/calibration.yaml --format mcap --detections detections/rig.yaml --out scene.mcap\n"
        "  rigcal export results/calibration.yaml --format mcap --recording run.bag --rig detect_rig.yaml "
        "--out scene.mcap",
    )
    e.add_argument("calibration", metavar="CALIBRATION")
    e.add_argument("--format", required=True, choices=list(FORMATS), metavar="FORMAT",
                   help="one of: " + ", ".join(FORMATS))
    e.add_argument("--out", metavar="FILE", help="output file (default: stdout)")
    e.add_argument("--urdf", metavar="ROBOT.urdf",
                   help="the robot's URDF: frame_ids are resolved in its links as `rigcal urdf` does "
                   "(camera optical frames, REP 103)")
    e.add_argument("--write-bounded", action="store_true",
                   help="with --urdf (or a calibration that recorded one): write the estimate also for "
                   "directions the calibration only bounds (by default the URDF's values, as `rigcal urdf`)")
    e.add_argument("--body-link", metavar="FRAME",
                   help="the frame the calibration is relative to (default: the reference sensor's "
                   "frame_id; a mocap calibration: mocap.yaml's robot_frame)")
    e.add_argument("--intrinsics", action="append", default=[], metavar="[SENSOR=]FILE",
                   help="--format kalibr: a camera file (Kalibr camchain, intrinsics JSON, CameraInfo "
                   "YAML, INI) for SENSOR (FILE#cam1 picks one camera of a multi-camera file); repeatable")
    e.add_argument("--rig", metavar="RIG.yaml",
                   help="--format kalibr: a detection rig or mocap.yaml naming each camera's intrinsics "
                   "(and topic); --format mcap: the detection rig of --recording")
    export_mcap.add_arguments(e)
    e.set_defaults(func=run)


def same_path(a: str, b: str) -> bool:
    """True when paths ``a`` and ``b`` name the same file (or would, once created)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def run(args, console) -> int:
    from rigcal.errors import InputError
    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.results import tf_export
    from rigcal.io.results.calibration_files import read_calibration_transforms
    from rigcal.io.results.frames import plan_with_checks

    for path in [args.urdf] + [i.split("=", 1)[-1] for i in args.intrinsics] + [args.rig]:
        if args.out and path and same_path(args.out, path.split("#")[0]):
            raise InputError(f"--out {args.out}: is an input file; choose another output path")
    if args.out and same_path(args.out, args.calibration):
        raise InputError(
            f"--out {args.out}: is the input calibration file; choose another output path"
        )
    if args.format == "mcap":
        return export_mcap.run(args, console)
    if args.detections or args.recording:
        raise InputError("--detections and --recording apply to --format mcap only")
    if args.format != "kalibr" and (args.intrinsics or args.rig):
        raise InputError("--intrinsics and --rig apply to --format kalibr or mcap only")
    cal = read_calibration_transforms(args.calibration)
    say = console.print if args.out else (lambda line: sys.stderr.write(line + "\n"))
    if args.format == "kalibr":
        from rigcal.io.results.camchain_export import camchain_text

        intrinsics = []
        for item in args.intrinsics:
            sensor, sep, path = item.partition("=")
            intrinsics.append((sensor, path) if sep else (None, item))
        text = camchain_text(cal, intrinsics, args.rig)
        count = text.count("\ncam")
        what = f"{count} camera(s) as a Kalibr camchain"
    else:
        urdf = None
        if args.urdf:
            from rigcal.io.results.urdf import read_urdf

            urdf = read_urdf(args.urdf)
        plan, warnings = plan_with_checks(cal, urdf, args.body_link, write_bounded=args.write_bounded)
        if urdf is not None and plan.root not in urdf.links:
            warnings.insert(0, f"the frame '{plan.root}' the calibration is relative to is not a "
                            f"link of {args.urdf}: the published transforms hang from a frame the "
                            "robot's tree lacks (set the reference's frame_id, or --body-link)")
        t = plan.transforms
        text = {
            "ros1-launch": lambda: tf_export.ros1_launch_text(t),
            "ros2-launch": lambda: tf_export.ros2_launch_py_text(t),
            "ros2-run": lambda: "\n".join(tf_export.ros2_run_commands(t)) + "\n",
            "yaml": lambda: tf_export.yaml_text(t, plan.root),
            "json": lambda: tf_export.json_text(t, plan.root),
        }[args.format]()
        for note in plan.notes:
            say(f"note: {note}")
        from rigcal.io.results.bounded import bounded_lines

        for line in bounded_lines(cal, plan, args.urdf, args.write_bounded):
            say(line)
        for w in warnings:
            say(f"warning: {w}")
        what = f"{len(t)} transform(s) from '{plan.root}'"
    if args.out:
        atomic_write_text(args.out, text)
        console.print(f"{what} written to {args.out}")
    else:
        sys.stdout.write(text)
    return 0
