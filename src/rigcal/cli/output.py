"""What every command prints: the console, progress, the pose and error tables, the verdict.

Light at import (rich is imported by the functions that draw), so that ``rigcal --help`` starts
fast. Tables are laid out to fit 80 columns (a console that is not a terminal is 80 columns wide
unless ``COLUMNS`` says otherwise); a cell too narrow is folded onto the next line, never cut
with an ellipsis. On a terminal progress is a live bar; elsewhere (CI logs, ``| tee``) it is
plain lines (:class:`PlainProgress`).
"""

from __future__ import annotations

import math
import os
import time
from typing import Callable

from rigcal.cli.codes import EXIT_FLAGGED

#: width of a console that is not a terminal, unless the environment's COLUMNS says otherwise
PLAIN_WIDTH = 80


def make_console(to_stderr: bool = False):
    """The console a command prints to: stdout, or stderr when stdout carries JSON."""
    from rich.console import Console

    console = Console(stderr=to_stderr, highlight=False)
    if not console.is_terminal:
        columns = os.environ.get("COLUMNS", "")
        console.width = int(columns) if columns.isdigit() and int(columns) >= 40 else PLAIN_WIDTH
    return console


# --------------------------------------------------------------------------------------------
# progress


class PlainProgress:
    """Progress as plain lines for a console that is not a terminal, e.g.
    ``detecting: 120/480 frames (25%)``: a line at the first update, then each time another
    10 % is done or when ``every_s`` seconds have passed since the last line (for a task of
    unknown total, only the latter), and a final line with the time taken (when the block ends
    without an error, unless the 100 % line had it).

    The subset of :class:`rich.progress.Progress` the commands use: a context manager with
    :meth:`add_task` and :meth:`update`.
    """

    def __init__(self, console, every_s: float = 5.0, clock: Callable[[], float] = time.monotonic,
                 eta: bool = False):
        self.console = console
        self.every_s = every_s
        self.clock = clock
        self.eta = eta  # each line also says the time elapsed and the time left
        self._tasks: list[dict] = []

    def __enter__(self) -> PlainProgress:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            for task in self._tasks:
                if task["done"] is not None and not task["final"]:
                    self._line(task, final=True)
        return False

    def add_task(self, description: str, total: float | None = None, unit: str = "", **_) -> int:
        now = self.clock()
        self._tasks.append({"description": description, "total": total or None, "unit": unit, "done": None,
                            "start": now, "last": now, "step": -1, "final": False})
        return len(self._tasks) - 1

    def update(self, task_id: int, completed: float | None = None, total: float | None = None, **_) -> None:
        task = self._tasks[task_id]
        if total is not None:
            task["total"] = total or None
        if completed is None or completed == task["done"]:
            return
        task["done"] = completed
        now = self.clock()
        if task["final"]:
            return
        if task["total"]:
            step = int(10 * min(completed / task["total"], 1.0))
            if step > task["step"] or now - task["last"] >= self.every_s:
                self._line(task, final=step == 10)
        elif task["step"] < 0 or now - task["last"] >= self.every_s:
            self._line(task)

    def _line(self, task: dict, final: bool = False) -> None:
        done, total = task["done"], task["total"]
        unit = f" {task['unit']}" if task["unit"] else ""
        if total:
            text = f"{task['description']}: {done:g}/{total:g}{unit} ({math.floor(100 * done / total)}%)"
            task["step"] = int(10 * min(done / total, 1.0))
        else:
            text = f"{task['description']}: {done:g}{unit}" if done or final else f"{task['description']}: started"
            task["step"] = 0
        now = self.clock()
        if final:
            text += f", {now - task['start']:.1f} s"
        elif self.eta and total and done:
            elapsed = now - task["start"]
            text += f", {elapsed:.0f} s elapsed, about {elapsed * (total - done) / done:.0f} s left"
        self.console.print(text, markup=False, highlight=False, soft_wrap=True)
        task["last"] = now
        task["final"] = final


def progress_bar(console, eta: bool = False):
    """The progress every long command shows: a live bar on a terminal, plain lines elsewhere."""
    if not console.is_terminal:
        return PlainProgress(console, eta=eta)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    columns = ["[progress.description]{task.description}", BarColumn(), MofNCompleteColumn()]
    if eta:
        columns += [TimeElapsedColumn(), TimeRemainingColumn()]
    return Progress(*columns, console=console)


def stage_progress(bar, units: dict[str, str] | None = None):
    """A ``progress(stage, done, total)`` callback that gives every stage its own task (a bar
    row, or its own plain lines); ``units`` names what a stage counts (``{"detecting": "frames"}``)."""
    tasks: dict[str, int] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=None, unit=(units or {}).get(stage, ""))
        bar.update(tasks[stage], completed=done, total=total or None)

    return progress


# --------------------------------------------------------------------------------------------
# tables


def table(title: str, columns, right: tuple[str, ...] | bool = ()):
    """A rich table whose cells fold rather than end in an ellipsis when the console is narrow;
    ``right``: the columns justified right (True: all but the first)."""
    from rich.table import Table

    t = Table(title=title)
    for i, col in enumerate(columns):
        r = (i > 0) if right is True else col in right
        t.add_column(col, justify="right" if r else "left", overflow="fold")
    return t


def pose_table(title: str, estimates, rpy_std_decimals: int = 2):
    """Two tables of sensor poses, each fitting 80 columns: x y z [m] and roll pitch yaw [deg],
    then their standard deviations [mm, deg] ("bnd": a direction only bounded by a constraint,
    which has no meaningful std)."""
    from rich.console import Group

    poses = table(title, ("sensor", "x (m)", "y (m)", "z (m)", "roll (deg)", "pitch (deg)", "yaw (deg)"),
                  right=True)
    stds = table("standard deviations", ("sensor", "x (mm)", "y (mm)", "z (mm)", "roll (deg)", "pitch (deg)",
                                         "yaw (deg)"), right=True)
    for name, est in estimates.items():
        x, y, z = est.xyz_m
        r, p, yw = est.rpy_deg
        s = est.std
        values = getattr(est, "bounded_values", None)
        bounded = (values if values is not None else getattr(est, "bounded", {})) or {}

        def cell(key: str, text: str) -> str:
            return "bnd" if key.split("_")[0] in bounded else text

        poses.add_row(name, f"{x:.4f}", f"{y:.4f}", f"{z:.4f}", f"{r:.3f}", f"{p:.3f}", f"{yw:.3f}")
        stds.add_row(
            name,
            *(cell(k, f"{s[k] * 1000:.1f}") for k in ("x_m", "y_m", "z_m")),
            *(cell(k, f"{s[k]:.{rpy_std_decimals}f}") for k in ("roll_deg", "pitch_deg", "yaw_deg")),
        )
    return Group(poses, stds)


def relative_table(relative):
    """The relative transforms ``T_to_from`` between sensors, as :func:`pose_table` (std from
    the same covariance as the poses, "bnd" where a bounded direction moves a value more than
    its std), and a note per pair whose Euler angles are near gimbal lock (roll and yaw std
    then mean little) with its rotation-vector std about the 'from' sensor's axes."""
    from rich.console import Group
    from rich.text import Text

    rows = {f"{r.to} <- {r.frm}": r for r in relative.values()}
    parts = [pose_table("relative transforms (T_to_from)", rows)]
    locked = [f"{k}: pitch {r.rpy_deg[1]:+.1f} deg; rotation std about {r.frm}'s x, y, z "
              f"{'/'.join(f'{v:.2f}' for v in r.rotation_std_deg)} deg"
              for k, r in rows.items() if getattr(r, "gimbal_lock", False)]
    if locked:
        parts.append(Text("near gimbal lock (Euler roll and yaw ill-defined): " + "; ".join(locked)))
    return Group(*parts)


def verdict_lines(result, console) -> None:
    """The consistency verdict, first thing on the terminal."""
    v = getattr(result, "verdict", None)
    if v is None:
        return
    if v.status == "flagged":
        console.print("[bold red]FLAGGED[/bold red]: the result contradicts its own noise model")
        for c in v.failed:
            console.print(f"  [red]{c.name}[/red]: {c.detail}")
    if v.status in ("flagged", "undetermined") and getattr(v, "undetermined", ()):
        console.print("[bold red]UNDETERMINED[/bold red]: the data do not determine every pose")
        for c in v.undetermined:
            console.print(f"  [red]{c.name}[/red]: {c.detail}")
    if v.status not in ("flagged", "undetermined"):
        console.print("[bold green]consistent[/bold green]: every check agrees with the noise model")
    for c in v.checks:
        if c.status == "note":
            console.print(f"  note ({c.name}): {c.detail}")


def not_written(console, what: str = "the result", code: int = EXIT_FLAGGED) -> int:
    """Say that a flagged (or undetermined: ``code`` 5) result was not written; the exit code
    for it."""
    why = "failed its consistency check" if code == EXIT_FLAGGED else "leaves a pose undetermined"
    console.print(
        f"[bold red]not written[/bold red]: {what} {why} "
        f"(exit code {code}); --force writes it anyway, with the verdict"
    )
    return code


def _mocap_residuals(result, console) -> None:
    """A motion-capture result's measured residuals (the RMS over every measured point, the
    same numbers as the measurements table and diagnostics.csv) and its warnings; no board
    terms (pairs, boards, PSE) - a mocap calibration has none."""
    e = table("measured residuals", ("sensor", "final, RMS over every point"))
    for key, v in result.rmse_m.items():
        e.add_row(key.split("-", 1)[-1], f"{v * 1000:.4g} mm")
    for key, v in result.reprojection_px.items():
        e.add_row(key.split("-", 1)[-1], f"{v:.4g} px")
    console.print(e)
    for w in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {w}")


def summary(result, console, verdict_first: bool = True) -> None:
    """A calibration result: the verdict, the poses and their stds, the errors between
    sensors, outliers, PSE noise and warnings."""
    if verdict_first:
        verdict_lines(result, console)
    console.print(pose_table(f"{result.mode.upper()} - reference {result.reference}", result.sensors))
    # every pair but those with the reference (the pose table above)
    pairs = {k: r for k, r in getattr(result, "relative", {}).items() if result.reference not in (r.to, r.frm)}
    if pairs:
        console.print(relative_table(pairs))
    priors = {n: e.prior for n, e in result.sensors.items() if getattr(e, "prior", None)}
    if priors:
        console.print("mounting priors (1 sigma around --initial; 0: held): " + "; ".join(
            f"{n}: " + ", ".join(f"{k} {v:g}" for k, v in p.items()) for n, p in priors.items()))
    if result.mode == "mocap":
        _mocap_residuals(result, console)
        return
    e = table("errors between sensors", ("pair", "RMSE (mm)", "cross-val RMSE (mm)", "worst board"))
    for pair, v in result.rmse_m.items():
        cv = result.cross_validation_rmse_m.get(pair)
        per = result.per_board_m.get(pair, {})
        worst = max(per.items(), key=lambda kv: kv[1]) if per else None
        e.add_row(
            pair,
            f"{v * 1000:.2f}",
            "-" if cv is None else f"{cv * 1000:.2f}",
            "-" if worst is None else f"#{worst[0]}: {worst[1] * 1000:.1f} mm",
        )
    for pair, v in result.reprojection_px.items():
        e.add_row(pair, f"{v:.3f} px (reprojection)", "-", "-")
    console.print(e)
    if result.outliers:
        console.print("outliers (excluded): " + "; ".join(f"{s}: boards {list(b)}" for s, b in result.outliers.items()))
    else:
        console.print("outliers (excluded): none")
    if result.noise_sigma_m:
        console.print(
            "PSE noise std (mm): "
            + "; ".join(f"{s}: {'/'.join(f'{v * 1000:.2f}' for v in sig)}" for s, sig in result.noise_sigma_m.items())
        )
    for w in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {w}")
