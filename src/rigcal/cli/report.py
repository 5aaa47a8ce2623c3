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
    data = read_report_data(folder)
    out = Path(args.out) if args.out else folder / REPORT_HTML_NAME
    atomic_write_text(out, render_report(data, str(folder / REPORT_JSON_NAME)))
    console.print(f"report written to {out}" + (f" ({data['note']})" if data.get("note") else ""),
                  markup=False, soft_wrap=True)
    return 0


def _study_page(folder, args, console) -> int:
    import json
    from pathlib import Path

    from rigcal.errors import InputError
    from rigcal.io._text import read_text
    from rigcal.io.atomic import atomic_write_text
    from rigcal.report.study_page import render_study

    source = folder / "study.json"
    try:
        study = json.loads(read_text(source, "study file"))
    except json.JSONDecodeError as exc:
        raise InputError(f"{source}: not JSON ({exc.msg}, line {exc.lineno})") from None
    out = Path(args.out) if args.out else folder / "study.html"
    atomic_write_text(out, render_study(study, str(source)))
    console.print(f"study page written to {out}", markup=False, soft_wrap=True)
    return 0
