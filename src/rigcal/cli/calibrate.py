"""``rigcal calibrate``: a rig from board detections (a manifest, the original tool's files, or a
recording detected first with ``--rig``)."""

from __future__ import annotations

import sys
from pathlib import Path

from rigcal.cli.args import count, subcommand

EPILOG = """examples:
  rigcal calibrate rig.yaml --mode fcpe --out results/
  rigcal calibrate rig.yaml --mode pse --reference lidar1 --out results/ --json
  rigcal calibrate --lidar lidar.csv --camera camera.csv --radar radar.csv --mode fcpe --out results/
  rigcal calibrate recording.bag --rig detect_rig.yaml --out results/   # detections kept in results/detections/
  rigcal calibrate results/detections/rig.yaml --mode pse --out results_pse/   # no detection again
  rigcal calibrate --batch fleet/car01 fleet/car02 fleet/car03 --out results/   # results/car01/ ...
  rigcal calibrate --batch fleet/* --out results/ --scheduler tcp://10.0.0.5:8786
  rigcal calibrate rig.yaml --initial robot.urdf --prior radar1:z_m=0.02,roll_deg=1,pitch_deg=1 --out results/

writes calibration.yaml, <sensor>.yaml, calibration.launch and report.html (open it in a
browser: verdict, poses, residuals, 3D detections, coverage; works offline)

exit codes: 0 consistent result written; 1 error; 2 usage; 3 the result contradicts its own
noise model (nothing written unless --force); with --batch: 4 some datasets failed or were
lost with the scheduler (the others are written; one line names them), 3 some were flagged,
1 all failed
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
    c.add_argument("--rig", metavar="RIG_YAML", help="detection rig: treat MANIFEST as a recording, detect, then calibrate "
                   "(the detections are kept in OUT/detections/, to calibrate again without detecting)")
    c.add_argument("--keep-detections", metavar="DIR",
                   help="with --rig: keep the detections (rig.yaml + one CSV per sensor) in DIR instead of "
                   "OUT/detections/, written before calibrating (also when the result is flagged)")
    c.add_argument("--lidar", action="append", default=[], metavar="FILE", help="lidar detections (repeatable)")
    c.add_argument("--camera", action="append", default=[], metavar="FILE", help="camera detections (repeatable)")
    c.add_argument("--radar", action="append", default=[], metavar="FILE", help="2D radar detections (repeatable)")
    c.add_argument("--radar3d", action="append", default=[], metavar="FILE", help="3D radar detections (repeatable)")
    c.add_argument("--mode", default="fcpe", choices=["mcpe", "fcpe", "pse"], help="configuration (default fcpe)")
    c.add_argument("--reference", help="reference sensor name (default: manifest's, else first lidar)")
    c.add_argument(
        "--batch", nargs="+", metavar="DIR",
        help="calibrate many datasets (e.g. a fleet of vehicles), each DIR holding a rig.yaml "
        "manifest; results go to OUT/<DIR's name>/ (the name as given), each written as it is "
        "calibrated; plain files are skipped with a note, one failing dataset does not stop the "
        "others, a summary table ends the run (docs/fleet.md)",
    )
    c.add_argument("--scheduler", default="local", metavar="local|serial|ADDRESS", help=SCHEDULER_HELP)
    c.add_argument("--out", required=True, metavar="DIR", help="output folder")
    c.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    c.add_argument("--ignore", metavar="FILE", help="original tool's ignore file (sensor -> CSV columns)")
    c.add_argument("--keep-outliers", action="store_true", help="do not search for bad detections")
    c.add_argument(
        "--hold-radar-plane",
        action="store_true",
        help="hold each 2D radar's z, roll and pitch at the initial guess (the limit of a prior "
        "z_m=0,roll_deg=0,pitch_deg=0)",
    )
    c.add_argument(
        "--prior", action="append", default=[], metavar="[SENSOR:]KEY=TOL,...",
        help="soft prior around the --initial pose: 1-sigma tolerances along / about the sensor's "
        "own axes, keys x_m y_m z_m roll_deg pitch_deg yaw_deg (0 holds a direction); without "
        "SENSOR: for every sensor without its own prior (the manifest's 'prior'); repeatable. "
        "docs/uncertainty.md",
    )
    c.add_argument("--initial", metavar="FILE",
                   help="initial guesses (nominal poses, which mounting priors are around): a previous "
                   "calibration.yaml, or the robot's URDF (each sensor at the link its frame_id names; "
                   "cameras: the optical frame; the written files then name frames by that URDF, as "
                   "`rigcal urdf` does)")
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
        help="write the result even when the consistency check flags it (exit code stays 3)",
    )
    c.set_defaults(func=run)


def initial_poses_from(path: str, dataset, reference: str | None):
    """``{sensor: T_reference_sensor}`` nominal poses from ``--initial`` (a calibration.yaml or
    the robot's URDF, :func:`rigcal.io.results.calibration_files.read_initial_poses`) for
    ``dataset``, relative to its reference (``reference`` or the dataset's default)."""
    from rigcal.io.results.calibration_files import read_initial_poses
    from rigcal.problem.initialise import default_reference

    if dataset is None:
        from rigcal.io.results.calibration_files import initial_is_urdf

        if initial_is_urdf(path):
            from rigcal.errors import InputError

            raise InputError(f"--initial {path}: a URDF needs one rig's sensors; with --batch give a "
                             "calibration.yaml, or calibrate each dataset on its own")
        return read_initial_poses(path)
    return read_initial_poses(path, dataset.sensors, reference or default_reference(dataset))


def initial_urdf(args):
    """The parsed URDF of ``--initial`` when it is one (else None): the written files name
    frames by it."""
    from rigcal.io.results.calibration_files import initial_is_urdf

    if not getattr(args, "initial", None) or not initial_is_urdf(args.initial):
        return None
    from rigcal.io.results.urdf import read_urdf

    return read_urdf(args.initial)


def options_from(args, dataset=None):
    """The :class:`CalibrationOptions` the command-line options ask for (``dataset``: the rig,
    needed to read nominal poses from a URDF)."""
    from rigcal.errors import InputError
    from rigcal.problem.calibrate import CalibrationOptions
    from rigcal.problem.priors import parse_prior_text

    default, per_sensor = None, {}
    for text in getattr(args, "prior", None) or []:
        sensor, prior = parse_prior_text(text)
        if sensor is None:
            if default is not None:
                raise InputError(f"--prior {text!r}: a second default prior (give one, or SENSOR:...)")
            default = prior
        elif sensor in per_sensor:
            raise InputError(f"--prior {text!r}: a second prior for '{sensor}'")
        else:
            per_sensor[sensor] = prior
    return CalibrationOptions(
        mode=args.mode,
        reference=args.reference,
        detect_outliers=not args.keep_outliers,
        hold_radar_plane=args.hold_radar_plane,
        initial=initial_poses_from(args.initial, dataset, args.reference) if args.initial else None,
        cross_validation_folds=args.cv_folds,
        pse_noise=args.pse_noise,
        prior=default,
        priors=per_sensor or None,
    )


def run(args, console) -> int:
    if args.batch:
        from rigcal.cli.batch import run_batch

        return run_batch(args, console)
    if args.scheduler != "local":
        from rigcal.errors import InputError

        raise InputError("--scheduler applies to --batch only (one dataset is calibrated in this process)")
    from rigcal.cli.codes import EXIT_FLAGGED
    from rigcal.cli.detect import detect_recording
    from rigcal.cli.output import not_written, summary
    from rigcal.errors import InputError
    from rigcal.io.atomic import staged_folder
    from rigcal.io.dataset.ignore import read_ignore_file
    from rigcal.io.dataset.manifest import dataset_from_files, load_manifest
    from rigcal.io.results.calibration import result_to_json_text
    from rigcal.io.results.report import write_calibration_set
    from rigcal.problem.calibrate import calibrate

    from rigcal.stages import StageClock, log

    files = args.lidar or args.camera or args.radar or args.radar3d
    inputs = (args.manifest, args.rig, args.initial, args.ignore, *args.lidar, *args.camera, *args.radar, *args.radar3d)
    from rigcal.io.atomic import check_output_folder

    check_output_folder(args.out, inputs=tuple(p for p in inputs if p))  # before any work
    if args.manifest and files:
        raise InputError("give either a manifest or --lidar/--camera/--radar files, not both")
    detection = None
    clock = StageClock()
    if args.rig:
        if not args.manifest or files:
            raise InputError("--rig needs a recording as the positional argument (and no --lidar/--camera/--radar)")
        detection = detect_recording(args.manifest, args.rig, console)
        dataset = detection.dataset
        clock.lap(f"detecting the board in {args.manifest}")
        if args.keep_detections:
            kept = keep_detections(dataset, args.keep_detections)
    elif args.keep_detections:
        raise InputError("--keep-detections applies to a recording detected with --rig")
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
    if detection is None:
        clock.lap(f"reading {len(dataset.sensors)} sensors x {dataset.num_boards} boards")
    log.info("calibrating: %s, reference %s", args.mode.upper(), args.reference or "the default")
    if args.plot:  # before the work, not after it
        from rigcal.extras import require

        require("matplotlib", "--plot (calibration.png)")
    urdf = initial_urdf(args)
    result = calibrate(dataset, options_from(args, dataset))
    clock.lap(f"calibration ({result.mode.upper()}, reference {result.reference}, verdict {result.verdict.status if result.verdict else 'not checked'})")
    if result.flagged and not args.force:
        summary(result, console)
        code = not_written(console)
        if detection is not None:
            rerun_hint(args, kept if args.keep_detections else None, dataset, console)
        return code
    # raw data: the lidar scans on the camera images, for the report
    raw = raw_images(args.manifest, args.rig, detection, result) if detection is not None else None
    with staged_folder(args.out) as stage:
        write_calibration_set(result, dataset, stage, raw, urdf=urdf)
        if detection is not None and not args.keep_detections:
            from rigcal.io.dataset.manifest import write_dataset

            write_dataset(detection.dataset, stage / DETECTIONS_DIR)
            kept = Path(args.out) / DETECTIONS_DIR / "rig.yaml"
        if args.plot:
            from rigcal.report.plot import plot_calibration

            plot_calibration(dataset, result, stage / "calibration.png")
    clock.lap(f"writing {args.out}/")
    if args.json:
        sys.stdout.write(result_to_json_text(result) + "\n")
    summary(result, console)
    if urdf is None:  # calibration.launch names cameras by rule 2 of the frame contract
        from rigcal.io.results.calibration import calibration_transforms
        from rigcal.io.results.frames import plan_with_checks

        for w in plan_with_checks(calibration_transforms(result))[1]:
            console.print(f"[yellow]warning:[/yellow] {w}")
    else:  # the written files keep the URDF's values for directions only bounded: say so
        from rigcal.io.results.bounded import bounded_lines
        from rigcal.io.results.calibration import calibration_transforms, frame_plan

        for line in bounded_lines(calibration_transforms(result), frame_plan(result, urdf), args.initial):
            console.print(line, markup=False, highlight=False, soft_wrap=True)
    console.print(f"results written to {args.out}/" + (" (FLAGGED, written with --force)" if result.flagged else ""))
    if detection is not None:
        rerun_hint(args, kept, dataset, console)
    return EXIT_FLAGGED if result.flagged else 0


#: where ``calibrate RECORDING --rig`` keeps the detections inside --out
DETECTIONS_DIR = "detections"


def keep_detections(dataset, folder: str) -> Path:
    """Write ``dataset`` (rig.yaml + CSVs) as the folder ``folder`` (a whole set, atomically);
    the path of its rig.yaml."""
    from rigcal.io.atomic import staged_folder
    from rigcal.io.dataset.manifest import write_dataset

    with staged_folder(folder) as stage:
        name = write_dataset(dataset, stage).name
    return Path(folder) / name


def rerun_hint(args, kept: Path | None, dataset, console) -> None:
    """Where the detections are, and the command that calibrates them in another mode (PSE
    only for a rig with a lidar or camera)."""
    if kept is None:
        console.print("the detections were not kept (nothing was written): --keep-detections DIR keeps them "
                      "whatever the verdict")
        return
    pse = any(s.kind.is_point_cloud for s in dataset.sensors)
    other = next(m for m in ("pse", "fcpe", "mcpe") if m != args.mode and (pse or m != "pse"))
    out = Path(args.out)
    console.print(f"detections kept in {kept}; another mode without detecting again:", soft_wrap=True)
    console.print(f"  rigcal calibrate {kept} --mode {other} --out {out.parent / (out.name + '_' + other)}",
                  soft_wrap=True, markup=False, highlight=False)


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
