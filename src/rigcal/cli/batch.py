"""``rigcal calibrate --batch DIR...``: one calibration per dataset (a fleet of vehicles), as
Dask tasks (:mod:`rigcal.study.scale`).

Each DIR holds a ``rig.yaml`` manifest (:data:`rigcal.io.dataset.manifest.MANIFEST_NAME`). The
manifests are read here, the calibrations run as tasks (workers only compute: they touch no
file), and each result is written here to ``OUT/<DIR's name>/`` exactly as ``rigcal calibrate
DIR --out OUT/<name>`` writes it (atomically; a flagged result only with ``--force``). A
dataset that cannot be read or calibrated is reported and skipped; a summary table ends the
run. Exit code: 0 all written and consistent; 3 some flagged; 5 some undetermined (none
flagged); 4 some failed (the rest written); 1 none calibrated.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import NamedTuple

from rigcal.cli.codes import EXIT_FLAGGED, EXIT_PARTIAL, EXIT_UNDETERMINED
from rigcal.errors import InputError, RigcalError


class Outcome(NamedTuple):
    """A dataset's calibration in a batch: the result, or why there is none."""

    name: str
    result: object | None
    error: str | None


def calibrate_task(options, dataset):
    """One task of a batch: ``calibrate(dataset, options)``, or the error's message."""
    from rigcal.problem.calibrate import calibrate

    try:
        return calibrate(dataset, options), None
    except RigcalError as exc:
        return None, str(exc)


def _names(dirs) -> list[str]:
    names = [Path(d).resolve().name if Path(d).is_dir() else Path(d).resolve().parent.name for d in dirs]
    seen: dict[str, str] = {}
    for d, n in zip(dirs, names):
        if n in seen:
            raise InputError(f"--batch: {seen[n]} and {d} would both write to OUT/{n}/; give datasets "
                             "with different folder names")
        seen[n] = d
    return names


def run_batch(args, console) -> int:
    import json

    from rigcal.cli.calibrate import exit_code, options_from
    from rigcal.cli.output import progress_bar, table
    from rigcal.io.atomic import staged_folder
    from rigcal.io.dataset.manifest import load_manifest
    from rigcal.io.results.calibration import result_to_json_text
    from rigcal.io.results.report import write_calibration_set
    from rigcal.study.scale import task_runner

    if args.manifest or args.rig or args.lidar or args.camera or args.radar or args.radar3d or args.ignore:
        raise InputError("--batch takes dataset folders only: no MANIFEST, --rig, --lidar/--camera/--radar "
                         "or --ignore with it")
    names = _names(args.batch)
    options = options_from(args)
    datasets, outcomes = {}, {}
    for d, name in zip(args.batch, names):
        try:
            datasets[name] = load_manifest(d)
        except RigcalError as exc:
            outcomes[name] = Outcome(name, None, str(exc))
    todo = [n for n in names if n in datasets]
    with progress_bar(console) as bar:
        task = bar.add_task("calibrating", total=len(todo), unit="datasets")
        with task_runner(args.scheduler) as runner:
            done = runner.map(calibrate_task, [datasets[n] for n in todo], shared=options, name="calibrate",
                              progress=lambda d, t: bar.update(task, completed=d, total=t))
    for name, (result, error) in zip(todo, done):
        outcomes[name] = Outcome(name, result, error)
    out = Path(args.out)
    status: dict[str, str] = {}
    for name in names:
        o = outcomes[name]
        if o.result is None:
            status[name] = "failed"
            continue
        code = exit_code(o.result)
        word = "flagged" if code == EXIT_FLAGGED else "undetermined"
        if code and not args.force:
            status[name] = f"{word}, not written"
            continue
        try:
            with staged_folder(out / name) as stage:
                write_calibration_set(o.result, datasets[name], stage)
        except RigcalError as exc:
            outcomes[name] = Outcome(name, None, str(exc))
            status[name] = "failed"
            continue
        status[name] = f"{word}, written (--force)" if code else "written"
    t = table(f"calibrate --batch: {len(names)} datasets, mode {args.mode}",
              ("dataset", "status", "RMSE per pair (mm) / error"))
    for name in names:
        o = outcomes[name]
        detail = (o.error or "") if o.result is None else ", ".join(
            f"{p} {v * 1000:.2f}" for p, v in o.result.rmse_m.items())
        t.add_row(name, status[name], detail)
    console.print(t)
    if args.json:
        doc = [{"dataset": n, "status": status[n], "error": outcomes[n].error,
                "result": json.loads(result_to_json_text(outcomes[n].result)) if outcomes[n].result else None}
               for n in names]
        sys.stdout.write(json.dumps(doc, indent=1) + "\n")
    failed = [n for n in names if status[n] == "failed"]
    flagged = [n for n in names if status[n].startswith("flagged")]
    undetermined = [n for n in names if status[n].startswith("undetermined")]
    console.print(f"{len(names) - len(failed) - len(flagged) - len(undetermined)} consistent, {len(flagged)} "
                  f"flagged, {len(undetermined)} undetermined, {len(failed)} failed; results in {out}/<dataset>/")
    if len(failed) == len(names):
        return 1
    if flagged:
        return EXIT_FLAGGED
    if undetermined:
        return EXIT_UNDETERMINED
    return EXIT_PARTIAL if failed else 0
