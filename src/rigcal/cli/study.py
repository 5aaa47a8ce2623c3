"""``rigcal study``: reproducible studies of the papers' experiments.

The options of ``rigcal study mocap`` live here (light: the parser is built on every start);
the study itself is :mod:`rigcal.study.mocap_study`, imported only when it runs.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rigcal.cli.args import WrappedHelpFormatter, count, number, subcommand

#: --scheduler (:mod:`rigcal.study.scale`; the parser must not import it)
SCHEDULER_HELP = ("where the draws run: 'local' (default: a Dask LocalCluster, one worker process "
                  "per core), 'serial' (in this process), or the ADDRESS of a running Dask "
                  "scheduler, e.g. tcp://10.0.0.5:8786")

#: the study's targets and sensors (:data:`rigcal.study.mocap_study.TARGETS` / ``SENSORS``)
TARGETS = ("diamond", "cylinder")
SENSORS = ("lidar", "camera")
#: lidar point matching (:data:`rigcal.problem.mocap.CORRESPONDENCES`)
CORRESPONDENCES = ("surface", "centroid")
#: bounds of the options (a seed is a non-negative integer for numpy's SeedSequence; a mocap
#: trial of 200 measurements takes minutes, the paper's largest is 30)
MAX_SEED = 2**63 - 1
MAX_TRIALS = 10000
MAX_MEASUREMENTS = 200

EPILOG = """examples:
  rigcal study mocap --trials 20
  rigcal study mocap --lidar-measurement keypoints      # the paper's corner-based simulation
  rigcal study mocap --lidar-noise-mm 10 --mcs-noise-mm 0.15
  rigcal study mocap --target cylinder --sensor lidar --trials 20
  rigcal study mocap --target diamond --sensor camera --mcs-noise-mm 0.15
  rigcal study mocap --trials 30 --out mocap_study/ --scheduler tcp://10.0.0.5:8786
"""


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``rigcal study mocap`` options to ``parser``."""
    parser.add_argument("--target", choices=TARGETS, default="diamond", help="target (default diamond)")
    parser.add_argument("--sensor", choices=SENSORS, default="lidar", help="sensor to calibrate (default lidar)")
    parser.add_argument("--trials", type=count(1, MAX_TRIALS), default=10,
                        help=f"seeded trials (default 10; at most {MAX_TRIALS})")
    parser.add_argument("--measurements", type=count(1, MAX_MEASUREMENTS), nargs="+", default=[5, 15, 30], metavar="N",
                        help=f"numbers of measurements per calibration (default 5 15 30; at most {MAX_MEASUREMENTS}: "
                        "a trial of 200 takes minutes)")
    parser.add_argument("--mcs-noise-mm", type=number(0.0, 1000.0), default=0.0,
                        help="motion-capture position noise per axis [mm] (default 0: exact; Vicon 0.15)")
    parser.add_argument("--seed", type=count(0, MAX_SEED), default=0, help="random seed (default 0; 0 to 2^63 - 1)")
    parser.add_argument("--overlapping", action="store_true", help="camera looks forward with the lidar")
    parser.add_argument("--lidar-measurement", choices=("keypoints", "points"), default="points",
                        help="lidar: every on-target point (default; the paper's choice on real data) or the "
                        "diamond's corners from ICP (the paper's simulation)")
    parser.add_argument("--correspondences", choices=CORRESPONDENCES, default="surface",
                        help="points without keypoints: closest surface point after the paper's matching "
                        "(default) or the paper's centroid-aligned matching throughout")
    parser.add_argument("--lidar-noise-mm", type=number(0.0, 1000.0), default=0.0, help="lidar range noise [mm] (default 0)")
    parser.add_argument("--same-data", action="store_true",
                        help="every trial sees the same captures, only the initial calibration changes")
    parser.add_argument("--json", action="store_true", help="print the table as JSON")
    parser.add_argument("--out", metavar="DIR", help="write study.md, study.json (every number) and mocap.png there")
    parser.add_argument("--scheduler", default="local", metavar="local|serial|ADDRESS",
                        help=SCHEDULER_HELP.replace("the draws", "the trials") + "; --same-data runs in this process")
    return parser


def add_parser(sub) -> None:
    st = subcommand(
        sub, "study",
        help="reproducible studies of the papers' experiments",
        description="Reproducible studies of the papers' simulated experiments.",
        formatter_class=WrappedHelpFormatter,
    )
    st_sub = st.add_subparsers(dest="study", metavar="STUDY")
    add_arguments(subcommand(
        st_sub, "mocap",
        help="Charron et al. Tables I-III: simulated motion-capture calibration",
        description="Reproduce Charron et al.'s simulated motion-capture calibration study "
        "(Tables I-III): simulated VLP-16 scans or camera images of the diamond or cylinder "
        "target, extraction, calibration from a perturbed start, many seeded trials; prints "
        "the table next to the paper's numbers.",
        epilog=EPILOG,
    ))
    pr = subcommand(
        st_sub, "prius",
        help="Domhof et al. Tables II-III and Figs. 7-8 on the shared Prius detections",
        description="Reproduce Domhof et al.'s Table II (single-board vs all-board lidar-stereo "
        "RMSE), Table III (median +- MAD of the RMSE over random sets of boards, per "
        "configuration and pair), Fig. 7 (the same for K = 3..29 boards) and Fig. 8 (10 boards, "
        "Gaussian noise of std sigma added to the lidar's detections) on a dataset manifest "
        "(default: the shared Prius detections, examples/prius/rig.yaml). Every RMSE is "
        "reported on all boards (the paper's choice) and on the boards the draw did not use. "
        "Prints Markdown tables next to the paper's values; --out DIR also writes study.md, "
        "study.json (every number) and fig7.png / fig8.png. The draws run as Dask tasks "
        "(--scheduler); the numbers are the same on any scheduler for the same --seed.",
        epilog="examples:\n  rigcal study prius --table III --draws 200 --out prius_study/\n"
        "  rigcal study prius examples/prius/rig.yaml --table II\n"
        "  rigcal study prius --table fig7 --draws 100 --out fig7/\n"
        "  rigcal study prius --table all --scheduler tcp://10.0.0.5:8786 --out prius_study/\n"
        "  rigcal study prius --table III --draws 20 --scheduler serial",
    )
    pr.add_argument("manifest", nargs="?", default=None, metavar="RIG.yaml",
                    help="dataset manifest (default: examples/prius/rig.yaml of this checkout)")
    pr.add_argument("--table", choices=("II", "III", "fig7", "fig8", "all"), default="all",
                    help="what to run (default all: II, III, fig7 and fig8)")
    pr.add_argument("--draws", type=count(1, 100000), default=None,
                    help="random board sets for each of Table III, each K of Fig. 7 and each sigma of "
                    "Fig. 8 (default: the paper's 200 for Table III, 100 for the figures)")
    pr.add_argument("--boards", type=count(3, 1000), default=10,
                    help="boards per set of Table III and Fig. 8 (default 10; Fig. 7 varies it)")
    pr.add_argument("--seed", type=count(0, MAX_SEED), default=0, help="random seed (default 0; 0 to 2^63 - 1)")
    pr.add_argument("--out", metavar="DIR", help="write study.md, study.json and the figures' PNGs there")
    pr.add_argument("--scheduler", default="local", metavar="local|serial|ADDRESS", help=SCHEDULER_HELP)
    pr.add_argument("--json", action="store_true", help="print study.json on stdout instead of Markdown")
    st.set_defaults(func=lambda args, console: run(args, console, st))


def mocap_parser() -> argparse.ArgumentParser:
    """The stand-alone parser of ``rigcal study mocap``'s options."""
    p = argparse.ArgumentParser(
        prog="rigcal study mocap",
        description="Reproduce Charron et al.'s simulated motion-capture calibration study (Tables "
        "I-III) on simulated VLP-16 scans or camera images, next to the paper's numbers.",
        epilog=EPILOG,
        formatter_class=WrappedHelpFormatter,
    )
    return add_arguments(p)


def mocap_main(argv: Sequence[str] | None = None) -> tuple[str, int]:
    """Parse ``argv`` (the options after ``rigcal study mocap``) and run the study; returns
    (text to print, exit code), argparse's text and code for ``--help`` or a usage error."""
    import contextlib
    import io

    from rigcal.study.mocap_study import run as run_study

    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            args = mocap_parser().parse_args(list(argv) if argv is not None else None)
    except SystemExit as exc:
        return buf.getvalue().rstrip("\n"), int(exc.code or 0)
    return run_study(args)


def run_prius(args, console) -> int:
    import time
    from pathlib import Path

    from rigcal.cli.output import progress_bar
    from rigcal.errors import InputError
    from rigcal.io.atomic import check_output_folder, staged_folder
    from rigcal.io.dataset.manifest import load_manifest
    from rigcal.study import prius
    from rigcal.study.scale import check_scheduler, task_runner

    manifest, shown = args.manifest, args.manifest  # shown: in study.json, never made absolute
    if manifest is None:
        manifest = Path(__file__).resolve().parents[3] / "examples" / "prius" / "rig.yaml"
        shown = "examples/prius/rig.yaml"
        if not manifest.is_file():
            raise InputError("no manifest given and examples/prius/rig.yaml not found beside the package")
    if args.out:  # before the study, not after it
        check_output_folder(args.out, inputs=(manifest,))
    scheduler = args.scheduler if "II" != args.table else "serial"
    if scheduler.strip() not in ("local", "serial"):
        check_scheduler(scheduler.strip())
    dataset = load_manifest(manifest)
    if args.boards > dataset.num_boards:
        raise InputError(f"--boards {args.boards}: {manifest} has only {dataset.num_boards} boards")
    tables = ("II", "III", "fig7", "fig8") if args.table == "all" else (args.table,)
    if args.out and {"fig7", "fig8"} & set(tables):  # before the draws, not after them
        from rigcal.extras import require

        require("matplotlib", "--out with Figs. 7/8 (fig7.png, fig8.png)")
    rows, seconds = [], {}
    with progress_bar(console) as bar:
        def progress(label):
            task = bar.add_task(label, total=None, unit="calibrations")
            return lambda d, t: bar.update(task, completed=d, total=t)

        with task_runner(scheduler) as runner:
            if "II" in tables:
                t0 = time.perf_counter()
                rows += prius.table_ii(dataset, progress=progress("Table II"))
                seconds["II"] = round(time.perf_counter() - t0, 1)
            drawn = [t for t in tables if t != "II"]
            if drawn:
                # one pool of tasks for every drawn table: shared draws run once, no idle
                # worker between tables
                t0 = time.perf_counter()
                names = {"III": "Table III", "fig7": "Fig. 7", "fig8": "Fig. 8"}
                rows += prius.draw_tables(dataset, drawn, draws=args.draws, k=args.boards, seed=args.seed,
                                          runner=runner, progress=progress(" + ".join(names[t] for t in drawn)))
                seconds[" + ".join(drawn)] = round(time.perf_counter() - t0, 1)
            where = runner.description
    meta = prius.study_meta(shown, tables, args.draws, args.boards, args.seed, where, seconds)
    text, data = prius.markdown(rows), prius.study_json(rows, meta)
    if args.out:
        import json

        from rigcal.report.study_page import render_study

        with staged_folder(args.out) as stage:
            figures = prius.plot_figures(rows, stage)
            links = "".join(f"\n![{p.stem}]({p.name})\n" for p in figures)
            (stage / "study.md").write_text(text + links)
            (stage / "study.json").write_text(data + "\n")
            (stage / "study.html").write_text(render_study(
                json.loads(data), "study.json", "Domhof et al. on the Prius data: Tables II/III, Figs. 7/8"))
    sys.stdout.write((data if args.json else text) + "\n")
    return 0


def run(args, console, parser: argparse.ArgumentParser) -> int:
    if args.study == "prius":
        return run_prius(args, console)
    if args.study != "mocap":
        parser.parse_args(["--help"])  # prints the studies and exits 0
    from rigcal.cli.output import progress_bar
    from rigcal.study.mocap_study import run as run_study

    if args.out:  # before the trials, not after them
        from rigcal.extras import require

        require("matplotlib", "--out (mocap.png)")
    with progress_bar(console) as bar:
        task = bar.add_task("mocap study", total=None, unit="trials")
        text, code = run_study(args, progress=lambda d, t: bar.update(task, completed=d, total=t))
    (sys.stdout if code == 0 else sys.stderr).write(text + "\n")
    return code
