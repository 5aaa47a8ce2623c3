"""``rigcal export --format mcap``: a verification scene for Foxglove
(:mod:`rigcal.io.results.mcap_scene`); the options it adds to ``rigcal export``."""

from __future__ import annotations


def add_arguments(e) -> None:
    """The scene's options on the ``export`` parser."""
    g = e.add_argument_group("--format mcap (a Foxglove scene; needs the mcap extra)")
    g.add_argument("--detections", metavar="RIG_YAML",
                   help="a dataset's rig.yaml (e.g. from `rigcal detect` or --keep-detections): each "
                   "sensor's board detections and the residual lines between sensors")
    g.add_argument("--recording", metavar="BAG",
                   help="a recording (bag or folder) to detect the board in with --rig: the detections "
                   "at their times, and a point cloud or image per sensor and placement")


def run(args, console) -> int:
    from rigcal.errors import InputError
    from rigcal.extras import require
    from rigcal.io.results.calibration_files import read_calibration_transforms
    from rigcal.io.results.frames import plan_with_checks
    from rigcal.io.results.mcap_scene import build_scene, write_scene

    if not args.out:
        raise InputError("--format mcap writes a binary file: give --out FILE (e.g. --out scene.mcap)")
    if bool(args.recording) != bool(args.rig):
        raise InputError("--recording and --rig go together (the rig says which topic is which sensor)")
    if args.recording and args.detections:
        raise InputError("give --recording with --rig, or --detections, not both")
    if args.intrinsics:
        raise InputError("--intrinsics applies to --format kalibr only")
    require("foxglove", "--format mcap")  # before any detection work
    cal = read_calibration_transforms(args.calibration)
    urdf = None
    if args.urdf:
        from rigcal.io.results.urdf import read_urdf

        urdf = read_urdf(args.urdf)
    plan, warnings = plan_with_checks(cal, urdf, args.body_link)  # the frames every writer emits
    for w in warnings:
        console.print(f"warning: {w}")
    transforms = plan.transforms
    measured = {s.frame_id: s.measured for s in (plan.reference, *plan.sensors)}
    dataset = detection = recording = rig = None
    if args.detections:
        from rigcal.io.dataset.manifest import load_manifest

        dataset = load_manifest(args.detections)
    if args.recording:
        from rigcal.cli.detect import detect_recording
        from rigcal.io.config.rig_config import load_rig_config
        from rigcal.io.recordings.open_any import open_any

        detection = detect_recording(args.recording, args.rig, console)
        rig = load_rig_config(args.rig)
        with open_any(args.recording) as recording:
            scene = build_scene(args.calibration, transforms, detection=detection, recording=recording,
                                rig=rig, measured=measured)
    else:
        scene = build_scene(args.calibration, transforms, dataset=dataset, measured=measured)
    write_scene(args.out, scene)
    console.print(f"{len(scene.transforms)} transform(s), {len(scene.marks)} board detection(s), "
                  f"{len(scene.residuals)} residual line set(s), {len(scene.clouds)} cloud(s), "
                  f"{len(scene.images)} image(s) written to {args.out} (open it in Foxglove)")
    return 0
