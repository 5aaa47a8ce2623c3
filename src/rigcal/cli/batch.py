"""``rigcal calibrate --batch DIR...``: one calibration per dataset (a fleet of vehicles), as
Dask tasks (:func:`rigcal.fleet.run_fleet` on :mod:`rigcal.study.scale`).

Each DIR holds a ``rig.yaml`` manifest (:data:`rigcal.io.dataset.manifest.MANIFEST_NAME`). The
manifests are read here, the calibrations run as tasks (workers only compute: they touch no
file), and each result is written here, as soon as it arrives, to ``OUT/<DIR's name>/``
(the name as given: a symlink keeps its own) exactly as ``rigcal calibrate DIR --out
OUT/<name>`` writes it (atomically; a flagged result only with ``--force``). A plain file among
the DIRs is skipped with a note; a dataset that is not there, cannot be read or calibrated, or
whose output folder is taken is reported and skipped; a summary table ends the run. A lost
worker's datasets run again; a lost scheduler ends the run with one line naming the datasets
not calibrated (the others are written). Exit code: 0 all written and consistent; 3 some
flagged; 4 some failed or missing (the rest written); 1 none calibrated.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rigcal.cli.codes import EXIT_FLAGGED, EXIT_PARTIAL
from rigcal.errors import InputError, printable

#: statuses of a written dataset (:func:`rigcal.fleet.run_fleet` adds failed and missing)
WRITTEN, FORCED, NOT_WRITTEN = "written", "flagged, written (--force)", "flagged, not written"


def calibrate_task(options, dataset):
    """One task of a batch: ``calibrate(dataset, options)`` (a RigcalError is that dataset's
    failure, :func:`rigcal.fleet.run_fleet`)."""
    from rigcal.problem.calibrate import calibrate

    return calibrate(dataset, options)


def _check_out(out: Path, entries) -> list:
    """Refuse an unusable ``--out`` before any work (a file, a dataset folder itself, a place
    that cannot be written); returns the entries, those whose ``OUT/<name>/`` is taken (a
    folder holding files rigcal did not write) marked with that problem."""
    import os

    from rigcal.io.atomic import check_output_folder, check_replaceable
    from rigcal.io.limits import path_stat

    st = path_stat(out, "--out")
    if st is not None and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder; --batch writes OUT/<dataset>/ folders into it")
    if st is None:
        check_output_folder(out)  # its parent can be written
    elif not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"--out {out}: no permission to write in it")
    checked = []
    for e in entries:
        if e.problem is None:
            target = out / e.name
            for candidate in (out, target):
                try:
                    same = os.path.samefile(candidate, e.path)
                except (OSError, ValueError):
                    same = False
                if same:
                    raise InputError(f"--out {out}: {candidate} is the dataset folder {e.path}; give another "
                                     "output folder")
            try:
                check_replaceable(target)
            except InputError as exc:
                e = e._replace(problem=f"output folder {exc}")
        checked.append(e)
    return checked


def run_batch(args, console) -> int:
    import json

    from rigcal.cli.calibrate import options_from
    from rigcal.cli.output import progress_bar, table
    from rigcal.fleet import FAILED, MISSING, fleet_entries, run_fleet
    from rigcal.io.atomic import staged_folder
    from rigcal.io.dataset.manifest import load_manifest
    from rigcal.io.results.calibration import result_to_json_text
    from rigcal.io.results.report import write_calibration_set
    from rigcal.study.scale import LOCAL, SERIAL, check_scheduler
    from rich.markup import escape

    if args.manifest or args.rig or args.lidar or args.camera or args.radar or args.radar3d or args.ignore:
        raise InputError("--batch takes dataset folders only: no MANIFEST, --rig, --lidar/--camera/--radar "
                         "or --ignore with it")
    out = Path(args.out)
    entries, notes = fleet_entries(args.batch)
    entries = _check_out(out, entries)
    if args.scheduler.strip() not in (LOCAL, SERIAL):
        check_scheduler(args.scheduler.strip())  # before anything is read or computed
    options = options_from(args)
    for note in notes:
        console.print(f"note: {note}", markup=False, soft_wrap=True)
    if not entries:
        raise InputError("--batch: no dataset folder among the arguments (" + ", ".join(printable(a)
                         for a in args.batch[:3]) + (", ..." if len(args.batch) > 3 else "") + ")")

    def write(entry, dataset, result) -> str:
        if result.flagged and not args.force:
            return NOT_WRITTEN
        with staged_folder(out / entry.name) as stage:
            write_calibration_set(result, dataset, stage)
        return FORCED if result.flagged else WRITTEN

    with progress_bar(console) as bar:
        task = bar.add_task("calibrating", total=len(entries), unit="datasets")
        run = run_fleet(entries, lambda e: load_manifest(e.path), calibrate_task, write, shared=options,
                        scheduler=args.scheduler, name="calibrate",
                        progress=lambda d, t: bar.update(task, completed=d, total=t))
    t = table(f"calibrate --batch: {len(entries)} datasets, mode {args.mode}",
              ("dataset", "status", "RMSE per pair (mm) / error"))
    for o in run.outcomes:
        detail = printable(o.error or "") if o.status in (FAILED, MISSING) else ", ".join(
            f"{p} {v * 1000:.2f}" for p, v in o.value.rmse_m.items())
        t.add_row(escape(printable(o.entry.name)), o.status, escape(detail))  # a name or path "a[/b]" is no markup
    console.print(t)
    if args.json:
        doc = [{"dataset": o.entry.name, "folder": str(o.entry.path), "status": o.status, "error": o.error,
                "result": json.loads(result_to_json_text(o.value)) if o.value is not None else None}
               for o in run.outcomes]
        sys.stdout.write(json.dumps(doc, indent=1) + "\n")
    failed = [o for o in run.outcomes if o.status in (FAILED, MISSING)]
    flagged = [o for o in run.outcomes if o.status in (NOT_WRITTEN, FORCED)]
    written = [o for o in run.outcomes if o.status in (WRITTEN, FORCED)]
    console.print(f"{len(entries) - len(failed) - len(flagged)} consistent, {len(flagged)} flagged, "
                  f"{len(failed)} failed; results in {printable(out)}/<dataset>/", markup=False, soft_wrap=True)
    if failed:  # one line on stderr says what is missing
        sys.stderr.write(f"rigcal: error: {_missing_line(run, failed, written, out, args.scheduler)}\n")
    if len(failed) == len(entries):
        return 1
    if flagged:
        return EXIT_FLAGGED
    return EXIT_PARTIAL if failed else 0


def _names(outcomes, limit: int = 8) -> str:
    names = [printable(o.entry.name) for o in outcomes]
    return ", ".join(names[:limit]) + (f", ... ({len(names)} in all)" if len(names) > limit else "")


def _missing_line(run, failed, written, out: Path, scheduler: str) -> str:
    """The one line that ends a batch with datasets not calibrated: which, and why in short (the
    table has each one's reason)."""
    from rigcal.fleet import MISSING

    missing = [o for o in failed if o.status == MISSING]
    others = [o for o in failed if o.status != MISSING]
    parts = []
    if run.lost:
        parts.append(f"--scheduler {printable(scheduler)}: {run.lost}; not calibrated: {_names(missing)}")
    elif missing:
        parts.append(f"not calibrated: {_names(missing)} ({printable(missing[0].error)})")
    if others:
        parts.append(f"failed: {_names(others)} (see the table)")
    total = len(run.outcomes)
    done = f"{len(written)} of {total} datasets written" + (f", complete, in {printable(out)}/" if written else "")
    return "; ".join(parts) + f"; {done}"
