"""``rigcal calibrate``: a rig from board detections (a manifest, the original tool's files, or a
recording detected first with ``--rig``)."""

from __future__ import annotations

import sys

from rigcal.cli.args import count, subcommand

EPILOG = """examples:
  rigcal calibrate rig.yaml --mode fcpe --out results/
  rigcal calibrate rig.yaml --mode pse --reference lidar1 --out results/ --json
  rigcal calibrate --lidar lidar.csv --camera camera.csv --radar radar.csv --mode fcpe --out results/
  rigcal calibrate --batch fleet/car01 fleet/car02 fleet/car03 --out results/   # results/car01/ ...
  rigcal calibrate --batch fleet/* --out results/ --scheduler tcp://10.0.0.5:8786

writes calibration.yaml, <sensor>.yaml, calibration.launch and report.html (open it in a
browser: verdict, poses, residuals, 3D detections, coverage; works offline)

exit codes: 0 consistent result written; 1 error; 2 usage; 3 flagged: the result contradicts
its own noise model, or a named mistake in the input (nothing written unless --force); 5
undetermined: a sensor's pose not determined to its kind's bound (--max-std; nothing written
unless --force); with --batch: 4 some datasets failed (the others are written), 3 some were
flagged, 5 some undetermined, 1 all failed
"""

#: --scheduler's help (:mod:`rigcal.study.scale`; not imported by the parser)
SCHEDULER_HELP = ("--batch: where the calibrations run: 'local' (default: a Dask LocalCluster, one "
                  "worker process per core), 'serial' (in this process), or the ADDRESS of a running "
                  "Dask scheduler, e.g. tcp://10.0.0.5:8786")


def add_parser(sub) -> None:
    c = subcommand(
        sub, "calibrate",
        help="calibrate a rig from board detections",
        description="Calibrate every sensor of a rig into the reference sensor's frame from "
        "detections of the circle board (manifest rig.yaml, or the original tool's CSV/YAML "
        "files with --lidar/--camera/--radar).",
        epilog=EPILOG,
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
    c.add_argument(
        "--batch", nargs="+", metavar="DIR",
        help="calibrate many datasets (e.g. a fleet of vehicles), each DIR holding a rig.yaml "
        "manifest; results go to OUT/<DIR's name>/, one failing dataset does not stop the others, "
        "a summary table ends the run",
    )
    c.add_argument("--scheduler", default="local", metavar="local|serial|ADDRESS", help=SCHEDULER_HELP)
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
    plot = c.add_mutually_exclusive_group()
    plot.add_argument("--plot", action="store_true",
                      help="also write calibration.png (all detections in the reference frame; "
                      "about 1 s more)")
    plot.add_argument("--no-plot", action="store_true", help="no calibration.png (the default)")
    c.add_argument(
        "--pse-noise", default="iterated", choices=["iterated", "identity"],
        help="PSE: per-sensor noise re-estimated until converged (default), or fixed at 1 "
        "(the original tool's variant)",
    )
    c.add_argument(
        "--force", action="store_true",
        help="write the result even when the consistency check flags it or a pose is undetermined "
        "(the exit code stays 3 / 5)",
    )
    c.add_argument(
        "--max-std", action="append", default=[], metavar="[KIND:]MM/DEG",
        help="largest std of a determined pose, per sensor kind or for all (repeatable; default "
        "50/1 for lidar, camera and radar3d, 100/2 for a 2D radar's in-plane pose), e.g. "
        "--max-std radar:150/3",
    )
    c.set_defaults(func=run)


def options_from(args):
    """The :class:`CalibrationOptions` the command-line options ask for."""
    from rigcal.io.results.calibration_files import read_initial_poses
    from rigcal.problem.calibrate import CalibrationOptions

    from rigcal.problem.determined import DETERMINED_BOUND, parse_bound

    bounds: dict[str, tuple[float, float]] = {}
    for text in getattr(args, "max_std", None) or []:
        kind, bound = parse_bound(text)
        bounds.update({k: bound for k in DETERMINED_BOUND} if kind is None else {kind: bound})
    return CalibrationOptions(
        mode=args.mode,
        max_std=bounds or None,
        reference=args.reference,
        detect_outliers=not args.keep_outliers,
        hold_radar_plane=args.hold_radar_plane,
        initial=read_initial_poses(args.initial) if args.initial else None,
        cross_validation_folds=args.cv_folds,
        pse_noise=args.pse_noise,
    )


def run(args, console) -> int:
    if args.batch:
        from rigcal.cli.batch import run_batch

        return run_batch(args, console)
    if args.scheduler != "local":
        from rigcal.errors import InputError

        raise InputError("--scheduler applies to --batch only (one dataset is calibrated in this process)")
    from rigcal.cli.codes import EXIT_FLAGGED, EXIT_UNDETERMINED
    from rigcal.cli.detect import detect_recording
    from rigcal.cli.output import not_written, summary
    from rigcal.errors import InputError
    from rigcal.io.atomic import staged_folder
    from rigcal.io.dataset.ignore import read_ignore_file
    from rigcal.io.dataset.manifest import dataset_from_files, load_manifest
    from rigcal.io.results.calibration import result_to_json_text
    from rigcal.io.results.report import write_calibration_set
    from rigcal.problem.calibrate import calibrate

    files = args.lidar or args.camera or args.radar or args.radar3d
    if args.manifest and files:
        raise InputError("give either a manifest or --lidar/--camera/--radar files, not both")
    detection = None
    if args.rig:
        if not args.manifest or files:
            raise InputError("--rig needs a recording as the positional argument (and no --lidar/--camera/--radar)")
        detection = detect_recording(args.manifest, args.rig, console)
        dataset = detection.dataset
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
    result = calibrate(dataset, options_from(args))
    code = exit_code(result)
    if code and not args.force:
        summary(result, console)
        return not_written(console, code=code)
    # raw data: the lidar scans on the camera images, for the report
    raw = raw_images(args.manifest, args.rig, detection, result) if detection is not None else None
    with staged_folder(args.out) as stage:
        write_calibration_set(result, dataset, stage, raw)
        if args.plot:
            from rigcal.report.plot import plot_calibration

            plot_calibration(dataset, result, stage / "calibration.png")
    if args.json:
        sys.stdout.write(result_to_json_text(result) + "\n")
    summary(result, console)
    forced = {EXIT_FLAGGED: " (FLAGGED, written with --force)",
              EXIT_UNDETERMINED: " (UNDETERMINED, written with --force)"}
    console.print(f"results written to {args.out}/" + forced.get(code, ""))
    return code


def exit_code(result) -> int:
    """0, or the exit code of a flagged (3, first) or undetermined (5) result."""
    from rigcal.cli.codes import EXIT_FLAGGED, EXIT_UNDETERMINED

    if result.flagged:
        return EXIT_FLAGGED
    v = getattr(result, "verdict", None)
    return EXIT_UNDETERMINED if v is not None and v.status == "undetermined" else 0


def raw_images(recording_path: str, rig_path: str, detection, result) -> list:
    """The report's lidar-on-camera images from the recording (none, with a warning, when the
    recording cannot be read again)."""
    import logging

    from rigcal.errors import RigcalError
    from rigcal.io.config.rig_config import load_rig_config
    from rigcal.io.recordings.open_any import open_any
    from rigcal.report.raw import raw_overlays

    try:
        rig = load_rig_config(rig_path)
        with open_any(recording_path) as rec:
            return raw_overlays(rec, rig, detection.placements, detection.dataset, result)
    except RigcalError as exc:
        logging.getLogger(__name__).warning("report: no lidar-on-image overlays (%s)", exc)
        return []
