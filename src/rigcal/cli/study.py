"""``rigcal study``: reproducible studies of the papers' experiments.

The options of ``rigcal study mocap`` live here (light: the parser is built on every start);
the study itself is :mod:`rigcal.study.mocap_study`, imported only when it runs.
"""

from __future__ import annotations

import argparse
import sys

from rigcal.cli.args import number, subcommand

#: the study's targets and sensors (:data:`rigcal.study.mocap_study.TARGETS` / ``SENSORS``)
TARGETS = ("diamond", "cylinder")
SENSORS = ("lidar", "camera")
#: lidar point matching (:data:`rigcal.problem.mocap.CORRESPONDENCES`)
CORRESPONDENCES = ("surface", "centroid")

EPILOG = """examples:
  rigcal study mocap --trials 20
  rigcal study mocap --lidar-measurement keypoints      # the paper's corner-based simulation
  rigcal study mocap --lidar-noise-mm 10 --mcs-noise-mm 0.15
  rigcal study mocap --target cylinder --sensor lidar --trials 20
  rigcal study mocap --target diamond --sensor camera --mcs-noise-mm 0.15
"""


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``rigcal study mocap`` options to ``parser``."""
    parser.add_argument("--target", choices=TARGETS, default="diamond", help="target (default diamond)")
    parser.add_argument("--sensor", choices=SENSORS, default="lidar", help="sensor to calibrate (default lidar)")
    parser.add_argument("--trials", type=int, default=10, help="seeded trials (default 10)")
    parser.add_argument("--measurements", type=int, nargs="+", default=[5, 15, 30], metavar="N",
                        help="numbers of measurements per calibration (default 5 15 30)")
    parser.add_argument("--mcs-noise-mm", type=number(0.0, 1000.0), default=0.0,
                        help="motion-capture position noise per axis [mm] (default 0: exact; Vicon 0.15)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--overlapping", action="store_true", help="camera looks forward with the lidar")
    parser.add_argument("--lidar-measurement", choices=("keypoints", "points"), default="points",
                        help="lidar: every on-target point (default; the paper's choice on real data) or the "
                        "diamond's corners from ICP (the paper's simulation)")
    parser.add_argument("--correspondences", choices=CORRESPONDENCES, default="surface",
                        help="points without keypoints: closest surface point after the paper's matching "
                        "(default) or the paper's centroid-aligned matching throughout")
    parser.add_argument("--lidar-noise-mm", type=number(0.0, 1000.0), default=0.0, help="lidar range noise [mm] (default 0)")
    parser.add_argument("--same-data", action="store_true",
                        help="every trial sees the same captures, only the initial calibration changes")
    parser.add_argument("--json", action="store_true", help="print the table as JSON")
    return parser


def add_parser(sub) -> None:
    st = subcommand(
        sub, "study",
        help="reproducible studies of the papers' experiments",
        description="Reproducible studies of the papers' simulated experiments.",
        formatter_class=argparse.HelpFormatter,
    )
    st_sub = st.add_subparsers(dest="study", metavar="STUDY")
    add_arguments(subcommand(
        st_sub, "mocap",
        help="Charron et al. Tables I-III: simulated motion-capture calibration",
        description="Reproduce Charron et al.'s simulated motion-capture calibration study "
        "(Tables I-III): simulated VLP-16 scans or camera images of the diamond or cylinder "
        "target, extraction, calibration from a perturbed start, many seeded trials; prints "
        "the table next to the paper's numbers.",
        epilog=EPILOG,
    ))
    st.set_defaults(func=lambda args, console: run(args, console, st))


def run(args, console, parser: argparse.ArgumentParser) -> int:
    if args.study != "mocap":
        parser.parse_args(["--help"])  # prints the studies and exits 0
    from rigcal.study.mocap_study import run as run_study

    text, code = run_study(args)
    (sys.stdout if code == 0 else sys.stderr).write(text + "\n")
    return code
