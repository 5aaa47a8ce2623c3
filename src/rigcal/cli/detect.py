"""``rigcal detect``: the board in a recording (bag or folder) to a dataset for ``rigcal calibrate``."""

from __future__ import annotations

from pathlib import Path

from rigcal.cli.args import subcommand

EPILOG = """examples:
  rigcal detect recording.bag --rig rig.yaml --out detections/
  rigcal detect rosbag2_dir/ --rig rig.yaml --out detections/ && rigcal calibrate detections/rig.yaml --out results/
"""


def add_parser(sub) -> None:
    t = subcommand(
        sub, "detect",
        help="detect the board in a recording (bag or folder) and write a dataset",
        description="Runs each sensor's board detector over a recording (ROS1 bag, ROS2 bag "
        "folder with sqlite3 or mcap storage, or a folder with one subfolder per sensor), finds "
        "the board placements automatically (stable periods matched across sensors) and writes "
        "rig.yaml + one CSV per sensor for `rigcal calibrate`.",
        epilog=EPILOG,
    )
    t.add_argument("recording", help="ROS1 .bag, ROS2 bag folder, or a folder of files")
    t.add_argument("--rig", required=True, metavar="RIG_YAML", help="sensors, topics and detector settings")
    t.add_argument("--out", required=True, metavar="DIR", help="output folder for rig.yaml + CSVs")
    t.set_defaults(func=run)


def detect_recording(recording_path: str, rig_path: str, console):
    """Detect the board in a recording with progress, print the detection table; the run."""
    from rigcal.cli.output import progress_bar, table
    from rigcal.detect.pipeline import run_detection
    from rigcal.io.recordings.open_any import open_any
    from rigcal.io.config.rig_config import load_rig_config

    rig = load_rig_config(rig_path)
    with open_any(recording_path) as rec, progress_bar(console, eta=True) as bar:
        task = bar.add_task("detecting", total=None, unit="frames")

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        run = run_detection(rec, rig, progress=progress)
    t = table(f"detection over {recording_path}",
              ("sensor", "frames", "detections", "rejections (reason: count)", "placements"))
    for name, st in run.stats.items():
        fails = ", ".join(f"{k}: {v}" for k, v in sorted(st.failures.items(), key=lambda kv: -kv[1])) or "-"
        t.add_row(name, str(st.frames), str(st.detections), fails, f"{st.placements}/{len(run.placements)}")
    console.print(t)
    console.print(f"{len(run.placements)} board placements found")
    for note in run.notes:
        console.print(f"note: {note}")
    return run


def run(args, console) -> int:
    from rigcal.io.atomic import check_output_folder, staged_folder
    from rigcal.io.dataset.manifest import write_dataset

    check_output_folder(args.out, inputs=(args.recording, args.rig))  # before any work

    found = detect_recording(args.recording, args.rig, console)
    with staged_folder(args.out) as stage:
        name = write_dataset(found.dataset, stage).name
    console.print(f"dataset written to {Path(args.out) / name}")
    return 0
