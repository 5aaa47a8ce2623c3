"""``rigcal check``: is a calibrated vehicle still calibrated? New board detections judged under
its calibration (:func:`rigcal.problem.check.check`); ``--batch``: a fleet on Dask."""

from __future__ import annotations

import math
import sys

from rigcal.cli.args import subcommand
from rigcal.cli.calibrate import SCHEDULER_HELP
from rigcal.cli.codes import EXIT_CANNOT_TELL, EXIT_MOVED, EXIT_PARTIAL

EPILOG = f"""examples:
  rigcal check results/calibration.yaml week12/rig.yaml              # new detections (a manifest)
  rigcal check results/ run.bag --rig detect_rig.yaml --out check/    # a recording, detected first
  rigcal check --batch week12/car01 week12/car02 --calibrations calib/ --out fleet/
  rigcal check --batch week12/* --calibrations calib/ --out fleet/ --scheduler tcp://10.0.0.5:8786

per sensor: 'unchanged', 'moved: 12 mm, 0.40 deg (p < 0.001)' with the direction, or 'cannot tell'
(no shared boards, too few); with the smallest move these boards find (80 % of the time). Three to
five boards seen by several sensors make a quick check. --out writes check.json and check.html;
--batch writes OUT/<vehicle>/check.* as each vehicle finishes, then OUT/fleet.html and fleet.json.

exit codes: 0 every sensor unchanged; {EXIT_MOVED} a sensor moved; {EXIT_CANNOT_TELL} none moved but some
cannot be told; 1 error. With --batch: {EXIT_MOVED} if any vehicle has a moved sensor, else {EXIT_PARTIAL} if
some vehicles failed, else {EXIT_CANNOT_TELL} if some sensor cannot be told; 1 if all failed or the Dask
scheduler was lost (the vehicles finished by then are written)
"""


def add_parser(sub) -> None:
    c = subcommand(
        sub, "check",
        help="is a calibrated rig still calibrated? (new detections vs calibration.yaml)",
        description="Judge new board detections under a stored calibration: per sensor, whether it moved "
        "since (and by how much, which way), stayed, or cannot be told; per sensor pair, the new "
        "residuals against the calibration's noise model.",
        epilog=EPILOG,
    )
    c.add_argument("calibration", nargs="?", help="calibration.yaml (or the result folder holding it)")
    c.add_argument("data", nargs="?", help="rig.yaml manifest of new detections (or a folder holding one); "
                   "with --rig, a recording to detect first")
    c.add_argument("--rig", metavar="RIG_YAML", help="detection rig: treat DATA as a recording, detect, then check")
    c.add_argument("--out", metavar="DIR", help="write check.json and check.html there (required with --batch)")
    c.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    c.add_argument("--alpha", type=false_alarm_rate, default=0.05, metavar="A",
                   help="false-alarm rate on an unchanged rig, shared by its sensors (default 0.05: the 95 %% level)")
    c.add_argument("--batch", nargs="+", metavar="DIR",
                   help="check many vehicles: each DIR holds a rig.yaml manifest of new detections; its calibration is "
                   "CALIBRATIONS/<DIR's name>/calibration.yaml (--calibrations), else DIR/calibration.yaml")
    c.add_argument("--calibrations", metavar="ROOT", help="--batch: the folder of the vehicles' calibrations "
                   "(as rigcal calibrate --batch writes it: ROOT/<vehicle>/calibration.yaml)")
    c.add_argument("--scheduler", default="local", metavar="local|serial|ADDRESS",
                   help=SCHEDULER_HELP.replace("the calibrations", "the checks"))
    c.set_defaults(func=run)


#: the smallest --alpha (a smaller false-alarm rate asks for more boards than a check has)
MIN_ALPHA = 1e-6


def false_alarm_rate(text: str) -> float:
    """``--alpha``: a number above 0 and below 0.5 (argparse makes a refusal a usage error naming
    the option, exit code 2)."""
    import argparse

    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a false-alarm rate such as 0.05, got {text!r}") from None
    if not (math.isfinite(x) and MIN_ALPHA <= x < 0.5):
        raise argparse.ArgumentTypeError(f"expected a false-alarm rate from {MIN_ALPHA:g} to below 0.5 "
                                         f"(e.g. 0.05), got {text!r}")
    return x


false_alarm_rate.__name__ = "number"


def text(value: object) -> str:
    """``value`` for a rich console with markup on: control characters escaped
    (:func:`rigcal.errors.printable`) and square brackets too, so that a path or name such as
    ``a[/b]`` is shown as it is (not a markup error)."""
    from rich.markup import escape

    from rigcal.errors import printable

    return escape(printable(value))


def exit_code(status: str) -> int:
    """The exit code of a check's (or diff's) status."""
    return {"moved": EXIT_MOVED, "cannot tell": EXIT_CANNOT_TELL}.get(status, 0)


def load_data(args, console):
    """The new detections: a manifest, or a recording detected first (``--rig``)."""
    from rigcal.cli.detect import detect_recording
    from rigcal.errors import InputError
    from rigcal.io.dataset.manifest import load_manifest

    if args.rig:
        return detect_recording(args.data, args.rig, console).dataset
    try:
        return load_manifest(args.data)
    except InputError:
        _refuse_calibration_as_data(args.data)
        raise


def _refuse_calibration_as_data(data: str) -> None:
    """InputError when DATA is a calibration (or its result folder) rather than new detections:
    the arguments given the wrong way round."""
    from pathlib import Path

    from rigcal.errors import InputError, printable
    from rigcal.io.dataset.manifest import MANIFEST_NAME

    p = Path(data)
    try:
        if p.is_dir() and not (p / MANIFEST_NAME).exists():
            p = p / "calibration.yaml"
        looks = p.name == "calibration.yaml" and p.is_file()
    except (OSError, ValueError):
        return
    if looks:
        raise InputError(f"DATA {printable(data)}: a calibration, expected new detections (a {MANIFEST_NAME} "
                         "manifest or its folder); the calibration comes first: rigcal check calibration.yaml "
                         "rig.yaml")


def run(args, console) -> int:
    from rigcal.errors import InputError

    if args.batch:
        if args.calibration or args.data or args.rig:
            raise InputError("--batch takes vehicle folders only: no CALIBRATION, DATA or --rig with it")
        if not args.out:
            raise InputError("--batch needs --out DIR (each vehicle's check.html and the fleet summary go there)")
        if args.json:
            raise InputError("--json applies to one check; --batch writes OUT/fleet.json")
        return run_batch(args, console)
    if args.calibrations:
        raise InputError("--calibrations applies to --batch only")
    if args.scheduler != "local":
        raise InputError("--scheduler applies to --batch only (one check runs in this process)")
    if not args.calibration or not args.data:
        raise InputError("give the calibration and the new detections: rigcal check calibration.yaml rig.yaml")
    if args.out:
        from rigcal.io.atomic import check_output_folder

        # before any work: not a file, not a user's folder, not (or holding) an input, writable
        check_output_folder(args.out, inputs=tuple(p for p in (args.calibration, args.data, args.rig) if p))
    from rigcal.io.results.stored import read_stored_calibration
    from rigcal.problem.check import CheckOptions, check

    stored = read_stored_calibration(args.calibration)
    dataset = load_data(args, console)
    result = check(stored, dataset, CheckOptions(alpha=args.alpha))
    data = result.to_dict()
    if args.out:
        from rigcal.io.atomic import staged_folder
        from rigcal.io.results.check_report import write_check

        with staged_folder(args.out) as stage:
            write_check(data, stage)
    if args.json:
        from rigcal.io.results.check_report import json_text

        sys.stdout.write(json_text(data))
    print_check(result, console)
    if args.out:
        console.print(f"check.json and check.html written to {text(args.out)}/")
    return exit_code(result.status)


def print_check(result, console) -> None:
    """A check on the terminal: the rig's verdict first, each sensor (worst first), the
    directions of the moved ones, the pairs' residuals, the power of the boards, warnings."""
    from rigcal.cli.output import table
    from rigcal.report.check_page import detectable_text

    from rigcal.errors import printable

    status = result.status
    head = {"moved": f"[bold red]MOVED[/bold red]: {text(', '.join(result.moved))}",
            "cannot tell": "[bold yellow]cannot tell[/bold yellow] for some sensors (none found moved)",
            "unchanged": "[bold green]unchanged[/bold green]: every sensor where it was calibrated"}[status]
    console.print(f"check of {text(result.calibration)} against {text(result.data or 'the data')} "
                  f"({result.num_boards} boards): "
                  + head)
    t = table("sensors (worst first)", ("sensor", "verdict", f"detectable ({result.power:.0%})"))
    for name, s in result.sensors.items():
        det = "-" if s.test is None else detectable_text(s.test.detectable_translation_m, s.test.detectable_rotation_deg)
        t.add_row(text(name), text(s.headline), det)
    console.print(t)
    for name, s in result.sensors.items():
        if s.status == "moved":
            console.print(f"  {printable(name)}: {printable(s.direction)}", markup=False)
    p = table("sensor pairs: reduced chi-square of the new residuals (about 1 when nothing moved)",
              ("pair", "boards", "RMS (mm)", "at calibration", "moved re-estimated"), right=True)
    for label, pc in result.pairs.items():
        p.add_row(text(label), str(pc.boards), f"{pc.rms_m * 1000:.1f}", f"{pc.before:.2f}", f"{pc.after:.2f}")
    console.print(p)
    dt, dr = result.detectable
    if math.isfinite(dt):
        console.print(f"power: these {result.num_boards} boards find moves of {detectable_text(dt, dr)} or more on "
                      f"every sensor told, {result.power:.0%} of the time; false alarms on at most {result.alpha:.0%} "
                      "of unchanged rigs", markup=False)
    else:
        console.print(f"power: no sensor could be told with these {result.num_boards} board(s)", markup=False)
    for w in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {text(w)}")


# --------------------------------------------------------------------------------------------
# fleets


def check_task(options, item):
    """One vehicle of a fleet on a worker: ``check(stored, dataset)`` as plain data (a
    RigcalError fails that vehicle alone, :func:`rigcal.fleet.run_fleet`)."""
    from rigcal.problem.check import check

    stored, dataset = item
    return check(stored, dataset, options).to_dict()


def run_batch(args, console) -> int:
    import stat
    import time
    from pathlib import Path

    from rigcal.cli.output import make_console, progress_bar, table
    from rigcal.errors import InputError, RigcalError, printable
    from rigcal.fleet import FAILED, MISSING, fleet_entries, run_fleet
    from rigcal.io.atomic import staged_folder
    from rigcal.io.dataset.manifest import load_manifest
    from rigcal.io.limits import path_stat
    from rigcal.io.results.check_report import check_fleet_output, vehicle_link, write_check, write_fleet
    from rigcal.io.results.stored import read_stored_calibration
    from rigcal.problem.check import CheckOptions
    from rigcal.report.check_page import fleet_summary, vehicle_row
    from rigcal.study.scale import LOCAL, SERIAL, check_scheduler

    out = Path(args.out)
    entries, notes = fleet_entries(args.batch)
    calibrations = Path(args.calibrations) if args.calibrations else None
    if calibrations is not None:
        st = path_stat(calibrations, "--calibrations")
        if st is None or not stat.S_ISDIR(st.st_mode):
            raise InputError(f"--calibrations {printable(calibrations)}: " + ("no such folder" if st is None else
                             "not a folder") + "; expected the folder of the vehicles' calibrations "
                             "(ROOT/<vehicle>/calibration.yaml, as rigcal calibrate --batch writes them)")

    def calibration_folder(entry) -> Path:
        return calibrations / entry.name if calibrations is not None else entry.path

    inputs = [p for e in entries if e.problem is None for p in (e.path, calibration_folder(e))]
    entries = check_fleet_output(out, entries, inputs + ([calibrations] if calibrations is not None else []))
    if args.scheduler.strip() not in (LOCAL, SERIAL):
        check_scheduler(args.scheduler.strip())  # before anything is read or computed
    for note in notes:
        console.print(f"note: {note}", markup=False, soft_wrap=True)
    if not entries:
        raise InputError("--batch: no vehicle folder among the arguments (" + ", ".join(
            printable(a) for a in args.batch[:3]) + (", ..." if len(args.batch) > 3 else "") + ")")
    names = [e.name for e in entries]

    def load(entry):
        return read_stored_calibration(calibration_folder(entry) / "calibration.yaml"), load_manifest(entry.path)

    def write(entry, item, data) -> str:  # in this process, as each vehicle finishes
        with staged_folder(out / entry.name) as stage:
            write_check(data, stage, title=f"{entry.name}: check of {data.get('calibration', '')}")
        return data["status"]

    t0 = time.monotonic()
    progress_console = make_console(to_stderr=True)
    with progress_bar(progress_console, eta=True) as bar:
        task = bar.add_task("checking", total=len(entries), unit="vehicles")
        run = run_fleet(entries, load, check_task, write, shared=CheckOptions(alpha=args.alpha),
                        scheduler=args.scheduler, name="check",
                        progress=lambda d, t: bar.update(task, completed=d, total=t))
    rows = []
    for o in run.outcomes:
        if o.status == MISSING:
            rows.append(vehicle_row(o.entry.name, None, f"not checked: {o.error}", status="not checked"))
        elif o.status == FAILED:
            rows.append(vehicle_row(o.entry.name, None, o.error if o.value is None
                                    else f"checked ({o.value['status']}) but not written: {o.error}"))
        else:
            rows.append(vehicle_row(o.entry.name, o.value, href=vehicle_link(o.entry.name)))
    note = ""
    missing = run.missing
    if run.lost:
        shown = ", ".join(missing[:8]) + (f", ... ({len(missing)} in all)" if len(missing) > 8 else "")
        note = (f"the Dask scheduler was lost after {len(entries) - len(missing)} of {len(entries)} vehicles "
                f"({run.lost}); not checked: {shown}")
    summary = fleet_summary(rows, args.alpha, note)
    write_fleet(summary, out)
    t = table(f"check --batch: {len(names)} vehicles, {time.monotonic() - t0:.1f} s (worst first)",
              ("vehicle", "status", "worst sensor: verdict"))
    for v in summary["vehicles"]:
        t.add_row(text(v["vehicle"]), v["status"],
                  text(f"{v['sensor']}: {v['headline']}" if v["sensor"] else v["headline"]))
    console.print(t)
    counts = summary["counts"]
    console.print(", ".join(f"{n} {s}" for s, n in counts.items() if n) + f"; {printable(out)}/fleet.html",
                  markup=False, soft_wrap=True)
    if missing:
        raise RigcalError(f"--scheduler {printable(args.scheduler)}: {note}; written: {out}/fleet.html and each "
                          "finished vehicle's folder")
    if counts["failed"]:  # one line on stderr says which (the table and fleet.html say why)
        failed = [printable(v["vehicle"]) for v in summary["vehicles"] if v["status"] == "failed"]
        shown = ", ".join(failed[:8]) + (f", ... ({len(failed)} in all)" if len(failed) > 8 else "")
        done = len(names) - len(failed)
        sys.stderr.write(f"rigcal: error: failed: {shown} (each one's reason is in the table and "
                         f"{printable(out)}/fleet.html); {done} of {len(names)} vehicles checked and written\n")
    if counts["failed"] == len(names):
        return 1
    if counts["moved"]:
        return EXIT_MOVED
    if counts["failed"]:
        return EXIT_PARTIAL
    return EXIT_CANNOT_TELL if counts["cannot tell"] else 0
