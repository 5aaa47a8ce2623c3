"""``rigcal urdf``: calibrated sensor poses into a URDF."""

from __future__ import annotations

from rigcal.cli.args import subcommand


def add_parser(sub) -> None:
    u = subcommand(
        sub, "urdf",
        help="write calibrated sensor poses into a URDF",
        description="Sets the origin of the joint carrying each calibrated sensor's link so that "
        "the URDF's forward kinematics reproduce the calibration (fixed joints between the "
        "parent frame and the sensor are taken into account). Only the changed origin values "
        "differ from the input; a new file is written unless --in-place (then INPUT.bak is kept). "
        "CALIBRATION: a rigcal calibration.yaml (of calibrate or mocap) / absolute.yaml, or the "
        "original tool's YAML {source, target, transform}. Sensors are found by frame_id; one the URDF lacks is "
        "skipped with a warning (or added: --add-missing); a camera's optical frame is handled as "
        "REP 103 (docs/guide.md). Directions the calibration only bounds (a 2D radar's z, roll and "
        "pitch without a prior) keep the URDF's values, one line per sensor says so; "
        "--write-bounded writes the estimate instead (docs/urdf.md).",
        epilog="examples:\n  rigcal urdf robot.urdf results/calibration.yaml --out robot_calibrated.urdf\n"
        "  rigcal urdf vehicle.urdf calibration.yaml --in-place\n"
        "  rigcal urdf robot.urdf results/calibration.yaml --write-bounded --out robot_calibrated.urdf",
    )
    u.add_argument("urdf_in", metavar="INPUT.urdf")
    u.add_argument("calibration", metavar="CALIBRATION")
    out_group = u.add_mutually_exclusive_group(required=True)
    out_group.add_argument("--out", metavar="OUTPUT.urdf")
    out_group.add_argument("--in-place", action="store_true", help="overwrite INPUT.urdf (a backup is kept)")
    u.add_argument("--body-link", help="link the poses are relative to (default: the calibration's "
                   "parent frame: the reference sensor's frame_id; a mocap calibration: mocap.yaml's "
                   "robot_frame)")
    u.add_argument("--add-missing", action="store_true",
                   help="add a link on a fixed joint from the body link for every calibrated frame the "
                   "URDF lacks (default: skip it with a warning)")
    u.add_argument("--write-bounded", action="store_true",
                   help="write the estimate also for directions the calibration only bounds (a 2D "
                   "radar's z, roll, pitch without a prior); by default the URDF's values are kept")
    u.add_argument(
        "--joint", action="append", default=[], metavar="LINK=JOINT",
        help="update JOINT for the sensor LINK (default: the joint whose child is LINK)",
    )
    u.set_defaults(func=run)


def run(args, console) -> int:
    from rigcal.errors import InputError
    from rigcal.io.results.bounded import bounded_lines
    from rigcal.io.results.calibration_files import read_calibration_transforms
    from rigcal.io.results.frames import plan_with_checks
    from rigcal.io.results.urdf import read_urdf, write_urdf

    cal = read_calibration_transforms(args.calibration)
    urdf = read_urdf(args.urdf_in)
    joint_for = {}
    for item in args.joint:
        if "=" not in item:
            raise InputError(f"--joint {item!r}: expected LINK=JOINT")
        link, joint = item.split("=", 1)
        joint_for[link] = joint
    # directions the calibration only bounds keep the URDF's values (--write-bounded: not)
    plan, warnings = plan_with_checks(cal, urdf, args.body_link, write_bounded=args.write_bounded)
    published = {s.frame_id: s.link for s in plan.sensors}
    joint_for = {published.get(link, link): joint for link, joint in joint_for.items()}
    written = write_urdf(
        args.urdf_in,
        args.urdf_in if args.in_place else args.out,
        {},
        plan.root,
        in_place=args.in_place,
        joint_for=joint_for or None,
        missing="add" if args.add_missing else "skip",
        frame_plan=plan,
    )
    body = plan.root
    done = [s.link for s in plan.sensors if s.link not in written.skipped and s.link not in written.added]
    console.print(
        f"updated {len(done)} sensor link(s) ({', '.join(done) or 'none'}) relative to "
        f"'{body}' -> {written.path}" + (f" (backup {written.backup})" if written.backup else "")
    )
    for frame in written.added:
        console.print(f"added link '{frame}' on a fixed joint from '{body}'")
    for note in written.notes:
        console.print(f"note: {note}")
    for line in bounded_lines(cal, plan, args.urdf_in, args.write_bounded):
        if line.split(":")[0] not in written.skipped:
            console.print(line, markup=False, highlight=False, soft_wrap=True)
    for frame in written.skipped:
        console.print(
            f"[yellow]warning:[/yellow] no link '{frame}' in {args.urdf_in}: skipped (set the "
            "sensor's frame_id to its URDF link, or --add-missing)"
        )
    for w in warnings:
        console.print(f"[yellow]warning:[/yellow] {w}")
    return 0
