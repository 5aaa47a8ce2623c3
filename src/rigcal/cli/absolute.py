"""``rigcal absolute``: every sensor to the vehicle body with an external laser scan."""

from __future__ import annotations

import sys

from rigcal.cli.args import number, subcommand


def add_parser(sub) -> None:
    a = subcommand(
        sub, "absolute",
        help="calibrate every sensor to the vehicle body with an external laser scan",
        description="Relates the rig to the body frame (Domhof et al. III-E): the external "
        "scanner is one more sensor of the board dataset (its detections of the placements it "
        "saw), so the joint calibration gives T_external_sensor for every rig sensor; wheel-rim "
        "labels (circle fits), single wheel-centre labels or markers in the external scan, plus "
        "the ground plane, give the body frame (origin below the rear axle centre, X forward, "
        "Y left, Z up); then T_body_sensor = T_body_external T_external_sensor. Writes "
        "absolute.yaml/.json, launch files and report.html.",
        epilog="example:\n  rigcal absolute rig.yaml --external leica --scan car_scan.pcd "
        "--labels wheels.yaml --out absolute/",
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
    a.add_argument("--hold-radar-plane", action="store_true",
                   help="hold every 2D radar's z, roll and pitch at the initial guess (with --initial: "
                   "the known mounting), as `rigcal calibrate --hold-radar-plane`")
    a.add_argument("--initial", metavar="FILE",
                   help="initial guesses: a calibration.yaml listing the external scanner (e.g. rigcal "
                   "calibrate rig.yaml --reference NAME; poses are taken relative to the scanner)")
    a.add_argument("--out", required=True, metavar="DIR")
    a.add_argument("--json", action="store_true", help="print absolute.json on stdout")
    a.add_argument(
        "--force", action="store_true",
        help="write the result even when the relative calibration's consistency check flags it (exit code stays 3)",
    )
    a.set_defaults(func=run)


def run(args, console) -> int:
    import math

    from rigcal.io.atomic import check_output_folder

    check_output_folder(args.out, inputs=tuple(p for p in (args.manifest, args.scan, args.labels, args.initial) if p))

    from rigcal.absolute.evaluate import ground_normal_angle
    from rigcal.absolute.labels import parse_labels_csv, parse_labels_yaml
    from rigcal.absolute.pipeline import absolute_calibration
    from rigcal.cli.codes import EXIT_FLAGGED
    from rigcal.cli.output import not_written, pose_table, verdict_lines
    from rigcal.errors import InputError
    from rigcal.io._text import read_text
    from rigcal.io.results.absolute import absolute_to_json_text, write_absolute
    from rigcal.io.results.report import write_report
    from rigcal.report.data import absolute_report
    from rigcal.io.atomic import staged_folder
    from rigcal.cli.calibrate import initial_poses_from
    from rigcal.problem.calibrate import CalibrationOptions
    from rigcal.io.dataset.manifest import load_manifest
    from rigcal.io.clouds import read_point_cloud

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
        options=CalibrationOptions(
            hold_radar_plane=args.hold_radar_plane,
            initial=initial_poses_from(args.initial, dataset, args.external) if args.initial else None,
        ),
    )
    ground = {name: ground_normal_angle(pts, result.T_body_sensor(name)) for name, pts in checks}
    verdict_lines(result.relative, console)
    if result.relative.flagged and not args.force:
        return not_written(console, "the relative calibration")
    with staged_folder(args.out) as stage:
        write_absolute(result, stage)
        write_report(absolute_report(result, dataset), stage)
    if args.json:
        sys.stdout.write(absolute_to_json_text(result) + "\n")
    b = result.body
    console.print(
        f"body frame '{result.body_frame}' ({args.origin}) from {args.method} labels: wheelbase "
        f"{b.wheelbase_m:.4f} m, tracks {b.track_rear_m:.4f} / {b.track_front_m:.4f} m, ground rms "
        f"{b.ground.rms_m * 1000:.1f} mm"
    )
    console.print(pose_table(
        f"T_body_sensor (body frame {result.body_frame})", result.sensors, rpy_std_decimals=3
    ))
    for name, g in ground.items():
        console.print(f"ground check {name}: normal {math.degrees(g.angle_rad):.3f} deg from body Z")
    for w in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {w}")
    console.print(f"written to {args.out}/ (absolute.yaml, absolute.json, launch files, report.html)")
    return EXIT_FLAGGED if result.relative.flagged else 0
