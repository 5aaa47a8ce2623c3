"""Writing what ``rigcal check`` and ``rigcal diff`` found: ``check.json`` / ``check.html`` of one
vehicle, ``diff.json``, and ``fleet.json`` / ``fleet.html`` of a fleet (:mod:`rigcal.report.check_page`).
Each file atomically; the texts are built before anything is written."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any, Mapping, Sequence
from urllib.parse import quote

from rigcal.io._text import json_safe
from rigcal.io.atomic import atomic_write_text

CHECK_JSON_NAME = "check.json"
CHECK_HTML_NAME = "check.html"
FLEET_JSON_NAME = "fleet.json"
FLEET_HTML_NAME = "fleet.html"


def json_text(data: Mapping[str, Any]) -> str:
    """Strict, indented JSON (NaN and infinities as null)."""
    return json.dumps(json_safe(dict(data)), indent=1, allow_nan=False) + "\n"


def write_check(data: Mapping[str, Any], out_dir: str | os.PathLike[str], title: str | None = None) -> list[Path]:
    """``check.json`` and ``check.html`` of a check's data (``CheckResult.to_dict()``) in
    ``out_dir``; the page is rendered from the JSON text's data."""
    from rigcal.report.check_page import render_check

    out = Path(out_dir)
    text = json_text(data)
    html = render_check(json.loads(text), str(out / CHECK_JSON_NAME), title)
    return [atomic_write_text(out / CHECK_JSON_NAME, text), atomic_write_text(out / CHECK_HTML_NAME, html)]


def vehicle_link(name: str) -> str:
    """The relative link from ``fleet.html`` to a vehicle's ``check.html`` (the folder name
    percent-encoded: a name is never read as a scheme or a path)."""
    return f"./{quote(name, safe='')}/{CHECK_HTML_NAME}"


def write_fleet(summary: Mapping[str, Any], out_dir: str | os.PathLike[str]) -> list[Path]:
    """``fleet.json`` and ``fleet.html`` of :func:`rigcal.report.check_page.fleet_summary`."""
    from rigcal.report.check_page import render_fleet

    out = Path(out_dir)
    text = json_text(summary)
    html = render_fleet(json.loads(text), str(out / FLEET_JSON_NAME))
    return [atomic_write_text(out / FLEET_JSON_NAME, text), atomic_write_text(out / FLEET_HTML_NAME, html)]


#: how a fleet.json / fleet.html that rigcal wrote begins (anything else there is a user's file)
_FLEET_SIGNS = {FLEET_JSON_NAME: b'"format": "rigcal-fleet-check"', FLEET_HTML_NAME: b"<title>rigcal fleet check</title>"}


def _ours(path: Path) -> bool:
    from rigcal.io.limits import path_stat

    st = path_stat(path, "--out file")
    if st is None:
        return True
    if not stat.S_ISREG(st.st_mode):
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return _FLEET_SIGNS[path.name] in head


def _ancestors(path: Path) -> set[Path]:
    """``path`` (resolved) and every folder above it."""
    r = path.resolve()
    return {r, *r.parents}


def check_fleet_output(out: str | os.PathLike[str], entries: Sequence[Any], inputs: Sequence[Path] = ()) -> list[Any]:
    """Refuse, before any work, a ``--out`` that ``rigcal check --batch`` could not write or that
    would write over its inputs: a file, a place that cannot be created or written, a folder
    holding a ``fleet.json`` / ``fleet.html`` rigcal did not write, or a folder where a vehicle's
    ``OUT/<vehicle>/`` (replaced as a whole) is, or holds, one of the ``inputs`` (the vehicles'
    folders, their calibration folders, the calibrations root) - InputError naming ``--out``.
    Returns ``entries`` (:class:`rigcal.fleet.FleetEntry`), those whose ``OUT/<vehicle>/`` holds
    files rigcal did not write marked with that problem (that vehicle fails alone)."""
    from rigcal.errors import InputError, printable
    from rigcal.io.atomic import check_output_folder, check_replaceable
    from rigcal.io.limits import path_stat

    out = Path(out)
    st = path_stat(out, "--out")
    if st is None:
        check_output_folder(out)  # its parent can be created and written
    elif not stat.S_ISDIR(st.st_mode):
        raise InputError(f"--out {printable(out)}: exists and is not a folder; --batch writes OUT/<vehicle>/ "
                         "folders and fleet.html into a folder")
    elif not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"--out {printable(out)}: no permission to write in it")
    else:
        for name in (FLEET_JSON_NAME, FLEET_HTML_NAME):
            if not _ours(out / name):
                raise InputError(f"--out {printable(out)}: holds a {name} rigcal did not write; give another "
                                 "output folder (or move that file)")
    held: dict[Path, Path] = {}  # every folder that is or holds an input -> that input
    existing = [Path(i) for i in inputs if path_stat(i, "input") is not None]
    for source in existing:
        for a in _ancestors(source):
            held.setdefault(a, source)
    if st is not None and out.resolve() in {s.resolve() for s in existing}:
        raise InputError(f"--out {printable(out)}: is an input of this run; give another output folder")
    checked = []
    for e in entries:
        if e.problem is None:
            target = (out / e.name).resolve() if st is not None else None
            if target is not None and target in held:
                how = "is" if held[target].resolve() == target else "holds"
                raise InputError(f"--out {printable(out)}: {printable(out / e.name)} {how} an input of this run "
                                 f"({printable(held[target])}) and would be replaced by the vehicle's check; give "
                                 "another output folder")
            try:
                check_replaceable(out / e.name)
            except InputError as exc:
                e = e._replace(problem=f"output folder {exc}")
        checked.append(e)
    return checked


__all__ = ["CHECK_HTML_NAME", "CHECK_JSON_NAME", "FLEET_HTML_NAME", "FLEET_JSON_NAME", "check_fleet_output",
           "json_text", "vehicle_link", "write_check", "write_fleet"]
