"""``rigcal mocap``: lidars and cameras to the robot frame with a motion-capture system."""

from __future__ import annotations

import math
import sys

from rigcal.cli.args import count, subcommand


def add_parser(sub) -> None:
    m = subcommand(
        sub, "mocap",
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
    )
    m.add_argument("config", metavar="CONFIG.yaml")
    m.add_argument("--out", required=True, metavar="DIR")
    m.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    m.add_argument("--max-overlays", type=count(0, 100000), default=None, metavar="N", help="overlay images per sensor")
    m.add_argument(
        "--force", action="store_true",
        help="write the result even when the consistency check flags it (exit code stays 3)",
    )
    m.set_defaults(func=run)


def measurements_table(run):
    """The measurements per sensor (:func:`rigcal.mocap.pipeline.summary_rows`) in 80 columns:
    frames, kept, rejected, the RMS residual under the initial -> final calibration and how far
    the calibration moved; and one line per sensor with its rejections by reason."""
    from rigcal.cli.output import table
    from rigcal.mocap.pipeline import SUMMARY_COLUMNS, summary_rows

    def g(v: float) -> str:
        return "-" if math.isnan(v) else f"{v:.4g}"

    t = table("measurements per sensor", ("sensor", "kind", "frames", "kept", "rejected",
                                          "RMS residual initial -> final", "moved mm / deg"),
              right=("frames", "kept", "rejected"))
    rejections = []
    for values in summary_rows(run):
        row = dict(zip(SUMMARY_COLUMNS, values))
        moved = "-" if math.isnan(row["change_mm"]) else f"{row['change_mm']:.1f} / {row['change_deg']:.2f}"
        t.add_row(row["sensor"], row["kind"], str(row["frames"]), str(row["kept"]), str(row["rejected"]),
                  f"{g(row['residual_initial'])} -> {g(row['residual_final'])} {row['unit']}", moved)
        if row["rejections"]:
            rejections.append(f"rejected ({row['sensor']}): {row['rejections']}")
    return t, rejections


def run(args, console) -> int:
    from rich.markup import escape

    from rigcal.io.atomic import check_output_folder

    check_output_folder(args.out, inputs=(args.config,))  # before any work

    from rigcal.cli.codes import EXIT_FLAGGED, EXIT_PARTIAL
    from rigcal.cli.output import not_written, progress_bar, summary, verdict_lines
    from rigcal.io.atomic import staged_folder
    from rigcal.io.results.calibration import result_to_json_text
    from rigcal.mocap.config import load_mocap_config
    from rigcal.mocap.pipeline import run_mocap, write_mocap_outputs

    config = load_mocap_config(args.config)
    with progress_bar(console) as bar:
        task = bar.add_task("extracting", total=None, unit="frames")
        found = run_mocap(config, progress=lambda d, t: bar.update(task, completed=d, total=t))

    def not_calibrated() -> None:
        for name, why in found.not_calibrated.items():
            console.print(f"[bold yellow]not calibrated[/bold yellow]: {escape(name)}: {escape(why)}",
                          soft_wrap=True)

    if found.result.flagged and not args.force:
        summary(found.result, console)
        not_calibrated()
        return not_written(console)
    with staged_folder(args.out) as stage:
        write_mocap_outputs(found, stage, max_overlays=args.max_overlays)
    if args.json:
        sys.stdout.write(result_to_json_text(found.result) + "\n")
    verdict_lines(found.result, console)
    table, rejections = measurements_table(found)
    console.print(table)
    for line in rejections:
        console.print(line, markup=False)
    summary(found.result, console, verdict_first=False)
    not_calibrated()
    notes = []
    if found.result.flagged:
        notes.append("FLAGGED, written with --force")
    if found.not_calibrated:
        notes.append(f"partial: {len(found.not_calibrated)} of {len(config.sensors)} sensors not calibrated "
                     f"({', '.join(found.not_calibrated)}), exit code {EXIT_PARTIAL}")
    console.print(f"results written to {args.out}/" + (f" ({'; '.join(notes)})" if notes else ""))
    if found.result.flagged:
        return EXIT_FLAGGED
    return EXIT_PARTIAL if found.not_calibrated else 0
