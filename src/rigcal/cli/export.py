"""``rigcal export``: a calibration as static TF publishers (ROS1/ROS2) or YAML/JSON."""

from __future__ import annotations

import os
import sys

from rigcal.cli import export_mcap
from rigcal.cli.args import subcommand

FORMATS = ("ros1-launch", "ros2-launch", "ros2-run", "yaml", "json", "mcap")


def add_parser(sub) -> None:
    e = subcommand(
        sub, "export",
        help="export a calibration as static TF publishers (ROS1/ROS2), YAML/JSON or a Foxglove scene",
        description="Writes every calibrated transform as ROS1 static_transform_publisher nodes "
        "(x y z yaw pitch roll parent child), a ROS2 Python launch file, `ros2 run tf2_ros "
        "static_transform_publisher` lines, or YAML/JSON 4x4 matrices, at full precision; or an MCAP "
        "scene for Foxglove with the frame tree, the board detections and the residuals.",
        epilog="examples:\n  rigcal export results/calibration.yaml --format ros2-launch --out calib.launch.py\n"
        "  rigcal export absolute.yaml --format ros2-run\n"
        "  rigcal export results/calibration.yaml --format mcap --detections detections/rig.yaml --out scene.mcap\n"
        "  rigcal export results/calibration.yaml --format mcap --recording run.bag --rig detect_rig.yaml "
        "--out scene.mcap",
    )
    e.add_argument("calibration", metavar="CALIBRATION")
    e.add_argument("--format", required=True, choices=list(FORMATS))
    e.add_argument("--out", metavar="FILE", help="output file (default: stdout)")
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
    from rigcal.io.results import tf_export
    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.results.calibration_files import read_calibration_transforms

    if args.out and same_path(args.out, args.calibration):
        raise InputError(
            f"--out {args.out}: is the input calibration file; choose another output path"
        )
    if args.format == "mcap":
        return export_mcap.run(args, console)
    if args.detections or args.recording or args.rig:
        raise InputError("--detections, --recording and --rig apply to --format mcap only")
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
