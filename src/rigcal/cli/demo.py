"""``rigcal demo``: a simulated rig (raw data or detections, or a motion-capture session)
calibrated and compared with the truth."""

from __future__ import annotations

from pathlib import Path

from rigcal.cli.args import subcommand

EPILOG = """examples:
  rigcal demo --out demo_out/
  rigcal demo --keep-bag --bag-format rosbag2-mcap --out demo_out/
  rigcal demo --mocap --out mocap_demo/ --seed 3
  rigcal demo --absolute --out absolute_demo/

the raw demo writes its simulated bag (230-570 MB) to a temporary folder and deletes it once the
board is detected; --keep-bag writes it into the output folder instead (recording.bag, or the
recording/ folder of a ROS2 bag), to run `rigcal detect` on it yourself. The demo's last lines
say which.
"""


def add_parser(sub) -> None:
    d = subcommand(
        sub, "demo",
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
        epilog=EPILOG,
    )
    d.add_argument("--out", default="demo_out", metavar="DIR", help="output folder (default demo_out)")
    d.add_argument("--seed", type=int, default=7, help="random seed (default 7)")
    d.add_argument("--boards", type=int, default=None,
                   help="board placements (default 12 raw, 29 detections-only)")
    d.add_argument("--detections-only", action="store_true", help="simulate detections directly (fast, no raw data)")
    d.add_argument("--mocap", action="store_true",
                   help="motion-capture demo: a lidar and two cameras with no shared view calibrated to the robot frame")
    d.add_argument("--absolute", action="store_true",
                   help="absolute calibration demo: the rig to the vehicle body from an external "
                   "scanner's scan and clicked rim points, written into a URDF (seconds)")
    d.add_argument("--holds", type=int, default=None, metavar="N",
                   help="--mocap: target poses held in each sensor's view (default 4)")
    d.add_argument("--bag-format", default=None, choices=["rosbag1", "rosbag2-sqlite3", "rosbag2-mcap"],
                   help="bag format of the raw demo (default rosbag1)")
    d.add_argument("--full-rate", action="store_true", help="simulate lidar and stereo at 10 Hz (slow)")
    d.add_argument("--keep-bag", action="store_true",
                   help="keep the simulated bag (230-570 MB) in the output folder; by default it is "
                   "written to a temporary folder and deleted after detection")
    d.set_defaults(func=run)


def print_demo(report, console) -> None:
    """The raw or detections-only demo: errors of every mode against the simulated truth."""
    from rigcal.cli.output import table

    console.print(report.description)
    t = table("errors against the simulated truth (T_reference_sensor)",
              ("mode", "sensor", "translation (mm)", "rotation (deg)",
               "2D radar: in-plane mm / yaw deg", "2D radar: z mm / tilt deg"),
              right=("translation (mm)", "rotation (deg)"))
    rmse_lines = []
    for o in report.outcomes:
        rmse_lines.append(f"{o.mode.upper()} RMSE between sensors (mm): "
                          + ", ".join(f"{k} {v * 1000:.1f}" for k, v in o.result.rmse_m.items()))
        for i, (name, e) in enumerate(o.errors.items()):
            radar2d = o.result.sensors[name].kind.value == "radar"
            t.add_row(
                o.mode.upper() if i == 0 else "",
                name,
                f"{e.translation_m * 1000:.1f}",
                f"{e.rotation_deg:.3f}",
                f"{e.in_plane_m * 1000:.1f} / {e.yaw_deg:.3f}" if radar2d else "",
                f"{e.out_of_plane_m * 1000:.1f} / {e.tilt_deg:.2f}" if radar2d else "",
            )
        for w in o.result.warnings:
            console.print(f"[yellow]{o.mode.upper()} warning:[/yellow] {w}")
    console.print(t)
    for line in rmse_lines:
        console.print(line)
    for n in report.notes:
        console.print(n)
    if any(s.kind.value == "radar" for o in report.outcomes[:1] for s in o.result.sensors.values()):
        console.print(
            "A 2D radar measures range and azimuth only: its in-plane pose is determined, its "
            "z and tilt only through the elevation limit (see the warnings)."
        )
    console.print(f"outputs written to {report.out_dir}/")
    modes = [o.mode for o in report.outcomes]
    first = "fcpe" if "fcpe" in modes else modes[0]
    others = ", ".join(f"{m}/" for m in modes if m != first)
    console.print("open this page in a browser" + (f" (the other modes: {others})" if others else "") + ":")
    console.print(str(report.out_dir / first / "report.html"), soft_wrap=True, markup=False, highlight=False)


def print_mocap_demo(report, console) -> None:
    """The motion-capture demo: every sensor's T_robot_sensor against the simulated truth."""
    from rigcal.cli.output import table, verdict_lines

    console.print(report.description)
    verdict_lines(report.run.result, console)
    errors = table("T_robot_sensor against the simulated truth",
                   ("sensor", "model", "initial error mm / deg", "final error mm / deg", "reported std mm / deg"),
                   right=("initial error mm / deg", "final error mm / deg", "reported std mm / deg"))
    counts = table("measurements", ("sensor", "frames", "kept", "rejected", "rejected by reason"),
                   right=("frames", "kept", "rejected"))
    for o in report.sensors:
        errors.add_row(
            o.sensor, f"{o.model} {o.kind}",
            f"{o.initial_error.translation_m * 1000:.1f} / {o.initial_error.rotation_deg:.2f}",
            f"{o.final_error.translation_m * 1000:.2f} / {o.final_error.rotation_deg:.4f}",
            f"{o.std_m * 1000:.2f} / {o.std_deg:.4f}",
        )
        counts.add_row(o.sensor, str(o.frames), str(o.kept), str(o.rejected),
                       ", ".join(f"{k} {v}" for k, v in o.rejections.items()) or "none")
    console.print(errors)
    console.print(counts)
    console.print(
        "std: root sum of squares of the per-axis standard deviations the calibration reports: "
        "from each sensor's errors estimated from its residuals - its own noise, the MCS's per "
        "capture, and per hold (the verdict's errors note) - widened for the few holds they "
        "rest on"
    )
    console.print(f"scene (run.bag, mocap.yaml, target, intrinsics, initial.json) written to {report.scene_dir}/")
    console.print(f"calibration (calibration.yaml, extrinsics.json, diagnostics.csv, overlays/) written to {report.results_dir}/")
    # one line, to copy
    console.print(f"run it again with: rigcal mocap {report.scene_dir / 'mocap.yaml'} --out {report.results_dir}",
                  soft_wrap=True)
    console.print("open this page in a browser:")
    console.print(str(report.results_dir / "report.html"), soft_wrap=True, markup=False, highlight=False)


def print_absolute_demo(report, console) -> None:
    """The absolute-calibration demo: every sensor's T_body_sensor against the simulated truth."""
    from rigcal.cli.output import table, verdict_lines

    console.print(report.description)
    verdict_lines(report.result.relative, console)
    b = report.result.body
    console.print(f"body frame from rim circles: wheelbase {b.wheelbase_m:.4f} m, ground rms "
                  f"{b.ground.rms_m * 1000:.1f} mm")
    t = table("T_body_sensor against the simulated truth",
              ("sensor", "translation (mm)", "rotation (deg)", "2D radar: in-plane mm / yaw deg",
               "2D radar: z mm / tilt deg"),
              right=("translation (mm)", "rotation (deg)"))
    for name, e in report.errors.items():
        radar2d = report.result.sensors[name].kind.value == "radar"
        t.add_row(name, f"{e.translation_m * 1000:.1f}", f"{e.rotation_deg:.3f}",
                  f"{e.in_plane_m * 1000:.1f} / {e.yaw_deg:.3f}" if radar2d else "",
                  f"{e.out_of_plane_m * 1000:.1f} / {e.tilt_deg:.2f}" if radar2d else "")
    console.print(t)
    console.print("A 2D radar's z and tilt are only bounded by its elevation field of view; the "
                  "lidar and camera errors come from their own noise (1 cm / 3 mm per centre) "
                  "over 20 boards.")
    console.print(f"scene (dataset/, scan.pcd, wheels.yaml, vehicle.urdf) written to {report.scene_dir}/")
    console.print(f"absolute calibration written to {report.results_dir}/; calibrated URDF: {report.urdf_path}")
    console.print(f"run it again with: {report.command}", soft_wrap=True)
    console.print("open this page in a browser:")
    console.print(str(report.results_dir / "report.html"), soft_wrap=True, markup=False, highlight=False)


def run(args, console) -> int:
    from rigcal.cli.output import progress_bar, stage_progress
    from rigcal.demo import absolute_demo, detections_demo, mocap_demo, raw_demo
    from rigcal.errors import InputError
    from rigcal.io.atomic import staged_folder

    if args.absolute:
        others = [flag for flag, given in (
            ("--mocap", args.mocap), ("--detections-only", args.detections_only),
            ("--holds", args.holds is not None), ("--bag-format", args.bag_format is not None),
            ("--full-rate", args.full_rate), ("--keep-bag", args.keep_bag)) if given]
        if others:
            raise InputError(f"--absolute does not take {', '.join(others)} (it takes --out, --seed and --boards)")
    elif args.mocap:
        others = [flag for flag, given in (
            ("--detections-only", args.detections_only), ("--boards", args.boards is not None),
            ("--bag-format", args.bag_format is not None), ("--full-rate", args.full_rate),
            ("--keep-bag", args.keep_bag)) if given]
        if others:
            raise InputError(f"--mocap does not take {', '.join(others)} (it takes --out, --seed and --holds)")
    elif args.holds is not None:
        raise InputError("--holds applies only to the motion-capture demo (--mocap)")
    if args.mocap or not (args.absolute or args.detections_only):
        from rigcal.extras import require

        require("cv2", "the raw-data demo (it renders and detects camera images; "
                "--detections-only runs without it)" if not args.mocap else
                "the motion-capture demo (it renders camera images)")
    out = Path(args.out)
    units = {"detecting": "frames", "extracting targets": "frames", "simulating raw data": "frames",
             "calibrating MCPE, FCPE, PSE": "modes"}
    # the whole demo folder is written as one set: a new folder beside --out, renamed at the end
    with staged_folder(out) as stage:
        if args.absolute:
            with progress_bar(console) as bar:
                report = absolute_demo(stage, seed=args.seed, boards=20 if args.boards is None else args.boards,
                                       progress=stage_progress(bar, units))
        elif args.mocap:
            with progress_bar(console) as bar:
                report = mocap_demo(stage, seed=args.seed, holds=4 if args.holds is None else args.holds,
                                    progress=stage_progress(bar, units), shown_as=out.absolute())
        elif args.detections_only:
            report = detections_demo(stage, seed=args.seed, boards=29 if args.boards is None else args.boards)
        else:
            with progress_bar(console) as bar:
                report = raw_demo(
                    stage, seed=args.seed, boards=12 if args.boards is None else args.boards,
                    bag_format=args.bag_format or "rosbag1", full_rate=args.full_rate,
                    keep_bag=args.keep_bag, progress=stage_progress(bar, units),
                )
    report = moved(report, stage, out)
    if args.absolute:
        print_absolute_demo(report, console)
    else:
        (print_mocap_demo if args.mocap else print_demo)(report, console)
    return 0


def moved(report, stage: Path, out: Path):
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
