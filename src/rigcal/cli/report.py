"""``rigcal report``: rebuild ``report.html`` of a result folder."""

from __future__ import annotations

from rigcal.cli.args import subcommand

EPILOG = """examples:
  rigcal report results/                      # rewrites results/report.html
  rigcal report mocap_out/ --out /tmp/mocap.html

RESULT_DIR is an output folder of rigcal calibrate, mocap or absolute, or of rigcal study
(its study.json becomes study.html). The page is built from its
report.json (written by every run); a folder written before reports existed is reported from
its calibration.yaml / absolute.yaml alone (no detections). The page is one file with plotly.js
embedded: it opens offline.
"""


def add_parser(sub) -> None:
    r = subcommand(
        sub, "report",
        help="rebuild report.html of a calibrate, mocap or absolute result folder",
        description="Write report.html - the verdict, the poses with their std, the relative "
        "transforms, every board's detections in the reference frame (interactive 3D), the "
        "residuals per pair and board with cross-validation, and the coverage with a hint where "
        "to put the next board - from a result folder, without the original inputs.",
        epilog=EPILOG,
    )
    r.add_argument("result_dir", metavar="RESULT_DIR",
                   help="output folder of rigcal calibrate, mocap, absolute or study")
    r.add_argument("--out", metavar="FILE",
                   help="where to write the page (default RESULT_DIR/report.html, or study.html)")
    r.set_defaults(func=run)


def run(args, console) -> int:
    from pathlib import Path

    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.results.report import REPORT_HTML_NAME, REPORT_JSON_NAME, read_report_data
    from rigcal.report.page import render_report

    folder = Path(args.result_dir)
    if (folder / "study.json").is_file() and not (folder / REPORT_JSON_NAME).exists() \
            and not (folder / "calibration.yaml").exists():
        return _study_page(folder, args, console)
    out = Path(args.out) if args.out else folder / REPORT_HTML_NAME
    check_page_out(out, folder, REPORT_HTML_NAME)
    data = read_report_data(folder)
    atomic_write_text(out, render_report(data, str(folder / REPORT_JSON_NAME)))
    console.print(f"report written to {out}" + (f" ({data['note']})" if data.get("note") else ""),
                  markup=False, soft_wrap=True)
    return 0


#: the page of a study's folder
STUDY_HTML_NAME = "study.html"
#: what an HTML page begins with (after blanks), in lower case
_HTML_STARTS = (b"<!doctype html", b"<html")


def check_page_out(out, folder, page_name: str) -> None:
    """Refuse, before any work, a page path that would write over an input: a file of the
    result folder other than its page (``report.json``, ``calibration.yaml``, ...), or any
    existing file that is not an HTML page (a page of an earlier run may be replaced)."""
    import os
    import stat
    from pathlib import Path

    from rigcal.errors import InputError
    from rigcal.io.limits import path_stat

    out, folder = Path(out), Path(folder)
    st = path_stat(out, "--out")
    if st is None:
        return
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"--out {out}: is a folder; expected the page's file name (e.g. {page_name})")
    try:
        inside = os.path.samefile(out.parent, folder)
    except OSError:
        inside = False
    if inside and out.name != page_name:
        raise InputError(f"--out {out}: is a file of the result folder {folder}, which the page is built from; "
                         f"give {folder / page_name} or a file elsewhere")
    head = b""
    if stat.S_ISREG(st.st_mode):  # (never opens a FIFO or a device)
        try:
            with open(out, "rb") as fh:
                head = fh.read(512).lstrip().lower()
        except OSError as exc:
            raise InputError(f"--out {out}: cannot read the file there ({exc.strerror or exc})") from None
    if not head.startswith(_HTML_STARTS):
        raise InputError(f"--out {out}: exists and is not an HTML page; rigcal report replaces only an earlier "
                         "page, never another file")


def _study_page(folder, args, console) -> int:
    from pathlib import Path

    from rigcal.io._text import load_json, read_text
    from rigcal.io.atomic import atomic_write_text
    from rigcal.report.study_page import render_study

    source = folder / "study.json"
    study = load_json(read_text(source, "study file"), str(source))
    out = Path(args.out) if args.out else folder / STUDY_HTML_NAME
    check_page_out(out, folder, STUDY_HTML_NAME)
    atomic_write_text(out, render_study(study, str(source)))
    console.print(f"study page written to {out}", markup=False, soft_wrap=True)
    return 0
