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
        "CALIBRATION: a rigcal calibration.yaml / absolute.yaml, or the original tool's YAML "
        "{source, target, transform}.",
        epilog="examples:\n  rigcal urdf robot.urdf results/calibration.yaml --out robot_calibrated.urdf\n"
        "  rigcal urdf vehicle.urdf calibration.yaml --in-place",
    )
    u.add_argument("urdf_in", metavar="INPUT.urdf")
    u.add_argument("calibration", metavar="CALIBRATION")
    out_group = u.add_mutually_exclusive_group(required=True)
    out_group.add_argument("--out", metavar="OUTPUT.urdf")
    out_group.add_argument("--in-place", action="store_true", help="overwrite INPUT.urdf (a backup is kept)")
    u.add_argument("--body-link", help="link the poses are relative to (default: the calibration's parent frame)")
    u.add_argument(
        "--joint", action="append", default=[], metavar="LINK=JOINT",
        help="update JOINT for the sensor LINK (default: the joint whose child is LINK)",
    )
    u.set_defaults(func=run)


def run(args, console) -> int:
    from rigcal.errors import InputError
    from rigcal.io.calibration_files import read_calibration_transforms
    from rigcal.io.urdf import write_urdf

    cal = read_calibration_transforms(args.calibration)
    joint_for = {}
    for item in args.joint:
        if "=" not in item:
            raise InputError(f"--joint {item!r}: expected LINK=JOINT")
        link, joint = item.split("=", 1)
        joint_for[link] = joint
    written = write_urdf(
        args.urdf_in,
        args.urdf_in if args.in_place else args.out,
        dict(cal.transforms),
        args.body_link or cal.parent_frame,
        in_place=args.in_place,
        joint_for=joint_for or None,
    )
    console.print(
        f"updated {len(cal.transforms)} sensor(s) ({', '.join(cal.transforms)}) relative to "
        f"'{args.body_link or cal.parent_frame}' -> {written.path}"
        + (f" (backup {written.backup})" if written.backup else "")
    )
    return 0
