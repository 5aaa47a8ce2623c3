"""A fleet: the same work on many datasets, one folder each (``rigcal calibrate --batch``; fleet
checks build on it too).

:func:`fleet_entries` turns command-line arguments into :class:`FleetEntry` values - named
after the argument as given (a symlink keeps its own name), plain files skipped with a note, a
folder that is not there or a name another entry already has reported as that entry's
problem - and :func:`run_fleet` runs a task on each entry's data on a scheduler
(:mod:`rigcal.study.scale`), hands every result to the caller's ``write`` as soon as it
arrives (so a run cut short keeps everything finished), runs again what a lost worker held,
and reports what it could not do. One bad entry never stops the others.

Library code: it prints nothing; the caller reports the outcomes.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

from rigcal.errors import InputError, RigcalError, printable
from rigcal.io.dataset.manifest import MANIFEST_NAME

#: statuses of a :class:`FleetOutcome` set by :func:`run_fleet` (``write`` returns the others)
FAILED = "failed"
MISSING = "missing"


class FleetEntry(NamedTuple):
    """One dataset of a fleet: the command-line ``argument``, the ``name`` its results go under
    (the last part of the argument as given), its folder ``path``, and ``problem``: why it
    cannot be run (no such folder, a name an earlier entry has), or None."""

    argument: str
    name: str
    path: Path
    problem: str | None = None


class FleetOutcome(NamedTuple):
    """What became of an entry: ``status`` is :data:`FAILED` (``error`` says why),
    :data:`MISSING` (its task never finished: the cluster was lost; ``error`` says so), or what
    ``write`` returned; ``value`` is the task's value (None without one)."""

    entry: FleetEntry
    status: str
    value: Any = None
    error: str | None = None


class FleetRun(NamedTuple):
    """The outcome of every entry (in entry order), what happened to the cluster (``lost``,
    None when it stayed up) and where the tasks ran (``where``)."""

    outcomes: tuple[FleetOutcome, ...]
    lost: str | None
    where: str

    @property
    def missing(self) -> list[str]:
        """Names of the entries whose task never finished."""
        return [o.entry.name for o in self.outcomes if o.status == MISSING]


def _name(argument: str, path: Path) -> str:
    name = path.name
    if name in ("", ".", ".."):  # "." or "/": the folder's own name
        name = path.resolve().name or "root"
    return name


def fleet_entries(arguments: Sequence[str], manifest_name: str = MANIFEST_NAME) -> tuple[list[FleetEntry], list[str]]:
    """The datasets of ``arguments`` (folders holding ``manifest_name``) and notes on what was
    left out. Each entry is named after its argument as given (``fleet/car01/`` -> ``car01``;
    a symlink keeps its own name, not its target's). A plain file is skipped with a note,
    unless it is a ``manifest_name`` file (then it stands for its folder); the same folder
    given twice runs once (a note). A folder that is not there, or whose name an earlier entry
    already has (both would write to the same place), is an entry with a ``problem``; nothing
    here refuses the fleet as a whole."""
    from rigcal.io.limits import path_stat

    entries: list[FleetEntry] = []
    notes: list[str] = []
    by_name: dict[str, FleetEntry] = {}
    seen: dict[tuple[int, int], str] = {}
    for argument in arguments:
        path = Path(argument)
        try:
            st = path_stat(path, "dataset folder")
        except InputError as exc:
            entries.append(FleetEntry(argument, printable(_name(argument, path)), path, str(exc)))
            continue
        if st is not None and not os.path.isdir(path):
            if path.name == manifest_name:
                path = path.parent
            else:
                notes.append(f"{printable(argument)}: not a folder, skipped (a dataset is a folder holding "
                              f"{manifest_name})")
                continue
        name = _name(argument, path)
        problem = None
        if st is None:
            problem = f"{path}: no such folder (expected a dataset folder holding {manifest_name})"
        else:
            ident = (os.stat(path).st_dev, os.stat(path).st_ino)
            if ident in seen:
                notes.append(f"{printable(argument)}: the same folder as {printable(seen[ident])}, run once")
                continue
            seen[ident] = argument
        if name in by_name and problem is None:
            problem = (f"{path}: has the name of {by_name[name].path}, given before it; both would write to "
                       f"OUT/{name}/ (rename one of the folders, or run it separately)")
        entry = FleetEntry(argument, name, path, problem)
        by_name.setdefault(name, entry)
        entries.append(entry)
    return entries, notes


class _Failed(NamedTuple):
    """A task's expected failure (its RigcalError's message), sent back as a value."""

    error: str


def _guarded(task_and_shared: tuple[Callable[[Any, Any], Any], Any], item: Any) -> Any:
    task, shared = task_and_shared
    try:
        return task(shared, item)
    except RigcalError as exc:
        return _Failed(str(exc))


def run_fleet(
    entries: Sequence[FleetEntry],
    load: Callable[[FleetEntry], Any],
    task: Callable[[Any, Any], Any],
    write: Callable[[FleetEntry, Any, Any], str],
    *,
    shared: Any = None,
    scheduler: str = "local",
    progress: Callable[[int, int], None] | None = None,
    name: str = "dataset",
) -> FleetRun:
    """Run ``task`` on every entry of a fleet and write each result as it arrives.

    For each entry without a ``problem``: ``item = load(entry)`` in this process (reading its
    files; a RigcalError fails that entry), then ``task(shared, item)`` on ``scheduler``
    (``local``, ``serial`` or a Dask scheduler's address, see :func:`rigcal.study.scale.task_runner`;
    ``task`` must be a module-level function, it computes and touches no file; a RigcalError it
    raises fails that entry), then, in this process as soon as that result arrives, ``status =
    write(entry, item, value)`` (e.g. an atomic folder of files; a RigcalError fails that
    entry). ``progress(done, total)`` counts the tasks.

    A task whose worker was lost runs again; if the scheduler is lost (or keeps no worker),
    everything written so far stays and the entries still running are :data:`MISSING`. A bad
    scheduler address is refused before any task (InputError naming it). Ctrl-C stops the run;
    what was written stays. Returns a :class:`FleetRun` with an outcome for every entry."""
    from rigcal.study.scale import task_runner

    outcomes: dict[int, FleetOutcome] = {}
    todo: list[int] = []
    items: list[Any] = []
    for i, entry in enumerate(entries):
        if entry.problem is not None:
            outcomes[i] = FleetOutcome(entry, FAILED, None, entry.problem)
            continue
        try:
            items.append(load(entry))
        except RigcalError as exc:
            outcomes[i] = FleetOutcome(entry, FAILED, None, str(exc))
            continue
        todo.append(i)

    def arrived(k: int, value: Any) -> None:
        i = todo[k]
        entry = entries[i]
        if isinstance(value, _Failed):
            outcomes[i] = FleetOutcome(entry, FAILED, None, value.error)
            return
        try:
            outcomes[i] = FleetOutcome(entry, write(entry, items[k], value), value)
        except RigcalError as exc:
            outcomes[i] = FleetOutcome(entry, FAILED, value, str(exc))

    lost, where = None, "nowhere (nothing to run)"
    if todo:
        with task_runner(scheduler, tasks=len(todo)) as runner:
            where = runner.description
            report = runner.run_each(_guarded, items, shared=(task, shared), on_result=arrived, progress=progress,
                                     name=name)
        lost = report.lost
        for k, why in report.missing.items():
            i = todo[k]
            outcomes[i] = FleetOutcome(entries[i], MISSING, None, why)
    return FleetRun(tuple(outcomes[i] for i in range(len(entries))), lost, where)


__all__ = ["FAILED", "MISSING", "FleetEntry", "FleetOutcome", "FleetRun", "fleet_entries", "run_fleet"]
