"""``rigcal diff``: per sensor, how two calibrations of one rig differ and whether the difference
is more than their uncertainty (:func:`rigcal.problem.diff.diff`)."""

from __future__ import annotations

import sys

from rigcal.cli.args import subcommand
from rigcal.cli.check import false_alarm_rate
from rigcal.cli.codes import EXIT_CANNOT_TELL, EXIT_MOVED

EPILOG = f"""examples:
  rigcal diff calib_2026-03/calibration.yaml calib_2026-09/calibration.yaml
  rigcal diff old/ new/ --json > diff.json

per sensor: the translation of its origin (reference frame), the rotation angle and axis, and
whether that is more than both calibrations' uncertainty (a chi-square test; a 2D radar's z, roll
and pitch are not compared: only its field of view bounds them).

exit codes: 0 every sensor unchanged; {EXIT_MOVED} a sensor moved; {EXIT_CANNOT_TELL} none moved but some
cannot be told; 1 error
"""


def add_parser(sub) -> None:
    c = subcommand(
        sub, "diff",
        help="compare two calibrations of one rig, sensor by sensor",
        description="Per sensor, the difference of two calibrations (translation, rotation angle and axis) "
        "and whether it is significant given both covariances.",
        epilog=EPILOG,
    )
    c.add_argument("old", help="the earlier calibration.yaml (or its result folder)")
    c.add_argument("new", help="the later calibration.yaml (or its result folder)")
    c.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    c.add_argument("--alpha", type=false_alarm_rate, default=0.05, metavar="A",
                   help="false-alarm rate when nothing changed, shared by the sensors (default 0.05)")
    c.set_defaults(func=run)


def run(args, console) -> int:
    from rigcal.cli.check import exit_code, text
    from rigcal.errors import printable
    from rigcal.cli.output import table
    from rigcal.io.results.check_report import json_text
    from rigcal.io.results.stored import read_stored_calibration
    from rigcal.problem.diff import diff
    from rigcal.report.check_page import detectable_text

    result = diff(read_stored_calibration(args.old), read_stored_calibration(args.new), alpha=args.alpha)
    if args.json:
        sys.stdout.write(json_text(result.to_dict()))
    head = {"moved": f"[bold red]MOVED[/bold red]: {text(', '.join(result.moved))}",
            "cannot tell": "[bold yellow]cannot tell[/bold yellow] for some sensors",
            "unchanged": "[bold green]unchanged[/bold green]: every difference within the uncertainty"}[result.status]
    console.print(f"diff of {text(result.old)} and {text(result.new)} (reference {text(result.reference)}): {head}")
    t = table("sensors (worst first)", ("sensor", "difference", "detectable (80%)"))
    for name, s in result.sensors.items():
        det = "-" if s.test is None else detectable_text(s.test.detectable_translation_m, s.test.detectable_rotation_deg)
        t.add_row(text(name), text(s.headline), det)
    console.print(t)
    for name, s in result.sensors.items():
        console.print(f"  {printable(name)}: {printable(s.direction)}", markup=False)
    for names, where in ((result.only_old, result.old), (result.only_new, result.new)):
        if names:
            console.print(f"not compared (only in {printable(where)}): " + ", ".join(map(printable, names)),
                          markup=False)
    return exit_code(result.status)
