"""Does the verdict refuse good data, and does it catch the usual mistakes? A population study.

:func:`draw_rig` draws a clean rig from a wide population (not one family):

* 1-3 lidars (isotropic noise), 1-3 cameras (3D circle centres; half of them stereo-like -
  lateral noise and depth noise growing with range squared - half isotropic), 0-2 2D radars
  (half with range / azimuth noise, half with Cartesian x / y noise; elevation field of view
  6-12 deg), 0-1 3D radar, each in an arbitrary mounting (:func:`rigcal.sim.rig.random_rig`);
* every sensor's noise drawn on its own: 2-20 mm (lidar, camera lateral, radar range or
  Cartesian), camera depth 0.2-2 mm at 1 m (5-50 mm at 5 m), radar azimuth 0.05-0.3 deg,
  3D radar elevation 0.05-0.5 deg;
* K = 6..29 boards 2-10 m away, facing the rig within about +-40 deg (yaw +-30, tilt +-20),
  reflectors spread over +-9 deg of elevation around the 2D radars' height (so they fill the
  radars' elevation fields of view, and some boards fall outside them).

:data:`FAULTS` are the usual mistakes, each injected into a copy of the clean rig's data:
a mirrored hole order in one sensor's file, one sensor in millimetres read as metres, one
sensor's detections 1 % too large, a board spacing of 0.25 m configured as 0.24, the
reflector offset configured as 0 (it is 0.105), the reflector in front of the plate on a third
of the boards, two sensors' detection files swapped (a lidar's and a camera's; and two sensors
of one kind, with the previous calibration given as ``initial``), one sensor's detection of one
board taken from another placement.

:func:`verdict_population` calibrates every rig (clean and with each fault) in every mode and
tallies what the verdict said. Every draw is seeded from ``(seed, rig)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from rigcal.dataset import BoardGeometry, Dataset, SensorKind
from rigcal.errors import InputError, RigcalError
from rigcal.geometry.se3 import from_rt, se3_exp
from rigcal.sim.rig import SimResult, SimSensor, make_rig_placements, random_rig, simulate

#: every fault of the study, in the order of the table
FAULT_NAMES = (
    "mirrored",
    "units_mm",
    "scale_1pct",
    "spacing",
    "offset_zero",
    "offset_side",
    "swap_kinds",
    "swap_same",
    "board_swap",
)


@dataclass(frozen=True, eq=False)
class PopulationRig:
    """A clean rig of the population: its simulation, and how each sensor's noise was drawn
    (``noise[name]``: e.g. ``{"model": "stereo", "sigma_m": 0.012, ...}``)."""

    sim: SimResult
    noise: dict
    T_rig_board: np.ndarray
    board: BoardGeometry
    extra_noise: dict  # name -> isotropic noise added after the simulation (m; radar: x, y)
    seed: tuple

    @property
    def dataset(self) -> Dataset:
        return self.sim.dataset

    @property
    def num_boards(self) -> int:
        return self.sim.dataset.num_boards


def _draw_noise(rng: np.random.Generator, s: SimSensor) -> tuple[SimSensor, dict, float]:
    """The sensor with its noise drawn; its description; isotropic noise to add afterwards."""
    mm = lambda: rng.uniform(0.002, 0.020)  # noqa: E731
    if s.kind is SensorKind.LIDAR:
        sigma = mm()
        return replace(s, sigma_m=sigma), {"model": "isotropic", "sigma_m": sigma}, 0.0
    if s.kind is SensorKind.CAMERA:
        if rng.random() < 0.5:
            lat, depth = mm(), rng.uniform(0.0002, 0.002)
            return (replace(s, sigma_m=lat, depth_sigma_at_1m_m=depth),
                    {"model": "stereo", "sigma_m": lat, "depth_sigma_at_1m_m": depth}, 0.0)
        sigma = mm()
        return replace(s, sigma_m=0.0, depth_sigma_at_1m_m=0.0), {"model": "isotropic", "sigma_m": sigma}, sigma
    if s.kind is SensorKind.RADAR:
        fov = rng.uniform(6.0, 12.0)
        if rng.random() < 0.5:
            rs, az = mm(), rng.uniform(0.05, 0.3)
            return (replace(s, range_sigma_m=rs, azimuth_sigma_deg=az, max_elevation_deg=fov, min_elevation_deg=-fov),
                    {"model": "range/azimuth", "range_sigma_m": rs, "azimuth_sigma_deg": az, "fov_deg": fov}, 0.0)
        sigma = mm()
        return (replace(s, range_sigma_m=0.0, azimuth_sigma_deg=0.0, max_elevation_deg=fov, min_elevation_deg=-fov),
                {"model": "cartesian", "sigma_m": sigma, "fov_deg": fov}, sigma)
    rs, az, el = mm(), rng.uniform(0.05, 0.3), rng.uniform(0.05, 0.5)
    return (replace(s, range_sigma_m=rs, azimuth_sigma_deg=az, elevation_sigma_deg=el),
            {"model": "range/azimuth/elevation", "range_sigma_m": rs, "azimuth_sigma_deg": az,
             "elevation_sigma_deg": el}, 0.0)


#: where the population's boards go (keyword arguments of make_rig_placements)
PLACEMENT = {"distance_m": (2.0, 10.0), "azimuth_spread_deg": 25.0, "elevation_spread_deg": 9.0,
             "yaw_deg": 30.0, "tilt_deg": 20.0}


def _simulate(sensors, T_rig_board, board, rng, extra_noise) -> SimResult:
    sim = simulate(sensors, T_rig_board, board=board, rng=rng)
    if not any(extra_noise.values()):
        return sim
    out = []
    for s in sim.dataset.sensors:
        sigma = extra_noise.get(s.name, 0.0)
        if sigma:
            pts = s.points + sigma * rng.standard_normal(s.points.shape)  # NaN stays NaN
            s = replace(s, points=pts)
        out.append(s)
    return replace(sim, dataset=replace(sim.dataset, sensors=tuple(out)))


def draw_rig(seed: int, index: int, num_boards: int | None = None) -> PopulationRig:
    """Rig ``index`` of the population of ``seed`` (see the module docstring); a draw whose
    sensors or boards cannot be placed (a mounting that sees too little of the board area) is
    drawn again from ``(seed, index, attempt)``."""
    for attempt in range(20):
        try:
            return _draw(np.random.default_rng([seed, index] + ([attempt] if attempt else [])), seed, index,
                         num_boards)
        except InputError:
            continue
    raise InputError(f"draw_rig: no rig drawn for seed {seed}, index {index} in 20 attempts")


def _draw(rng: np.random.Generator, seed: int, index: int, num_boards: int | None) -> PopulationRig:
    counts = dict(n_lidar=int(rng.integers(1, 4)), n_camera=int(rng.integers(1, 4)),
                  n_radar=int(rng.integers(0, 3)), n_radar3d=int(rng.integers(0, 2)))
    K = int(rng.integers(6, 30)) if num_boards is None else int(num_boards)
    sensors = random_rig(rng, **counts)
    drawn = [_draw_noise(rng, s) for s in sensors]
    sensors = tuple(d[0] for d in drawn)
    noise = {s.name: d[1] for s, d in zip(sensors, drawn)}
    extra = {s.name: d[2] for s, d in zip(sensors, drawn)}
    board = BoardGeometry()
    T_rig_board = make_rig_placements(rng, sensors, K, board=board, **PLACEMENT)
    sim = _simulate(sensors, T_rig_board, board, rng, extra)
    return PopulationRig(sim, noise, T_rig_board, board, extra, (seed, index))


def three_radar_rig(seed: int, boards: int = 20) -> SimResult:
    """The Prius-like rig (:func:`rigcal.sim.rig.prius_like_rig`) with a second 2D radar and a
    3D radar, ``boards`` placements: with three radars the reflector offset is told apart from
    their poses (a single 2D radar's translation absorbs most of it)."""
    from rigcal.sim.rig import _pose, prius_like_rig

    extra = (
        SimSensor("radar2", SensorKind.RADAR, _pose((3.5, 0.6, 0.55), (0.0, -0.5, 20.0)),
                  range_sigma_m=0.01, azimuth_sigma_deg=0.2),
        SimSensor("radar3d1", SensorKind.RADAR3D, _pose((3.6, -0.6, 0.7), (0.0, 2.0, -15.0)),
                  range_sigma_m=0.01, azimuth_sigma_deg=0.2, elevation_sigma_deg=0.3),
    )
    rng = np.random.default_rng(seed)
    sensors = prius_like_rig() + extra
    return simulate(sensors, make_rig_placements(rng, sensors, boards, min_fraction=0.8), rng=rng)


# --------------------------------------------------------------------------------------------
# faults


@dataclass(frozen=True, eq=False)
class Fault:
    """A fault injected into a rig's data: the ``dataset`` to calibrate, calibration options
    it needs (``initial`` poses for a swap of two sensors of one kind), whom it concerns
    (``sensors``) and ``what`` was done."""

    name: str
    dataset: Dataset
    sensors: tuple[str, ...]
    what: str
    options: dict = field(default_factory=dict)


def _with_points(dataset: Dataset, name: str, points: np.ndarray) -> Dataset:
    return replace(dataset, sensors=tuple(replace(s, points=points) if s.name == name else s
                                          for s in dataset.sensors))


def _pick(rng, names: Sequence[str]) -> str | None:
    return str(names[int(rng.integers(len(names)))]) if names else None


def _point_cloud(dataset: Dataset) -> list[str]:
    return [s.name for s in dataset.sensors if s.kind.is_point_cloud]


def _radars(dataset: Dataset) -> list[str]:
    return [s.name for s in dataset.sensors if s.kind.is_radar]


def fault_mirrored(rig: PopulationRig, rng) -> Fault | None:
    name = _pick(rng, _point_cloud(rig.dataset))
    pts = rig.dataset.sensor(name).points[:, [1, 0, 3, 2]]
    return Fault("mirrored", _with_points(rig.dataset, name, pts), (name,), f"{name}: TR, TL, BR, BL")


def fault_units_mm(rig: PopulationRig, rng) -> Fault | None:
    name = _pick(rng, list(rig.dataset.names))
    return Fault("units_mm", _with_points(rig.dataset, name, rig.dataset.sensor(name).points * 1000.0),
                 (name,), f"{name} in mm")


def fault_scale_1pct(rig: PopulationRig, rng) -> Fault | None:
    name = _pick(rng, list(rig.dataset.names))
    return Fault("scale_1pct", _with_points(rig.dataset, name, rig.dataset.sensor(name).points * 1.01),
                 (name,), f"{name} x 1.01")


def _resimulate(rig: PopulationRig, board: BoardGeometry, rng) -> SimResult:
    return _simulate(rig.sim.sensors, rig.T_rig_board, board, rng, rig.extra_noise)


def fault_spacing(rig: PopulationRig, rng) -> Fault | None:
    sim = _resimulate(rig, replace(rig.board, spacing_m=0.25), rng)
    return Fault("spacing", replace(sim.dataset, board=replace(rig.board, spacing_m=0.24)), (),
                 "spacing 0.25 configured as 0.24")


def fault_offset_zero(rig: PopulationRig, rng) -> Fault | None:
    if not _radars(rig.dataset):
        return None
    return Fault("offset_zero", replace(rig.dataset, board=replace(rig.board, reflector_offset_m=0.0)), (),
                 "reflector offset configured as 0")


def fault_offset_side(rig: PopulationRig, rng) -> Fault | None:
    """The reflector in front of the plate (at +offset along the front normal) on a third of
    the boards: the radars see it 2 x offset nearer than the configured board says."""
    radars = _radars(rig.dataset)
    if not radars:
        return None
    K = rig.num_boards
    boards = np.sort(rng.choice(K, size=max(1, K // 3), replace=False))
    shift = from_rt(np.eye(3), [0.0, 0.0, 2.0 * rig.board.reflector_offset_m])
    T = np.array(rig.T_rig_board)
    T[boards] = T[boards] @ shift
    moved = _simulate(rig.sim.sensors, T, rig.board, rng, rig.extra_noise).dataset
    out = []
    for s in rig.dataset.sensors:
        if s.kind.is_radar:
            pts = np.array(s.points)
            pts[boards] = moved.sensor(s.name).points[boards]
            s = replace(s, points=pts)
        out.append(s)
    return Fault("offset_side", replace(rig.dataset, sensors=tuple(out)), tuple(radars),
                 f"reflector in front of the plate on boards {boards.tolist()}")


def _swap(dataset: Dataset, a: str, b: str) -> Dataset:
    pa, pb = dataset.sensor(a).points, dataset.sensor(b).points
    return _with_points(_with_points(dataset, a, pb), b, pa)


def fault_swap_kinds(rig: PopulationRig, rng) -> Fault | None:
    lidars = [s.name for s in rig.dataset.sensors if s.kind is SensorKind.LIDAR]
    cameras = [s.name for s in rig.dataset.sensors if s.kind is SensorKind.CAMERA]
    a, b = _pick(rng, lidars), _pick(rng, cameras)
    return Fault("swap_kinds", _swap(rig.dataset, a, b), (a, b), f"{a} <-> {b}")


def fault_swap_same(rig: PopulationRig, rng) -> Fault | None:
    """Two sensors of one kind swapped; the previous calibration (the truth, moved by 1 cm /
    0.5 deg per sensor) given as ``initial``, as when a vehicle is calibrated again."""
    groups: dict[SensorKind, list[str]] = {}
    for s in rig.dataset.sensors:
        groups.setdefault(s.kind, []).append(s.name)
    choices = [g for g in groups.values() if len(g) >= 2]
    if not choices:
        return None
    group = choices[int(rng.integers(len(choices)))]
    a, b = (str(x) for x in rng.choice(group, size=2, replace=False))
    ref = next(s.name for s in rig.dataset.sensors if s.kind is SensorKind.LIDAR)
    initial = {}
    for s in rig.dataset.names:
        d = rng.normal(size=6)
        d[:3] *= math.radians(0.5) / np.linalg.norm(d[:3])
        d[3:] *= 0.01 / np.linalg.norm(d[3:])
        initial[s] = rig.sim.truth_T(ref, s) @ se3_exp(d) if s != ref else np.eye(4)
    return Fault("swap_same", _swap(rig.dataset, a, b), (a, b), f"{a} <-> {b}", {"initial": initial})


def fault_board_swap(rig: PopulationRig, rng) -> Fault | None:
    """One sensor's detection of board k is its detection of board j (another placement)."""
    names = [s.name for s in rig.dataset.sensors if np.sum(s.detected) >= 2]
    name = _pick(rng, names)
    s = rig.dataset.sensor(name)
    ks = np.flatnonzero(s.detected)
    k, j = (int(x) for x in rng.choice(ks, size=2, replace=False))
    pts = np.array(s.points)
    pts[k] = s.points[j]
    return Fault("board_swap", _with_points(rig.dataset, name, pts), (name,), f"{name} board {k} <- board {j}",
                 {"board": k, "source": j})


FAULTS: dict[str, Callable[[PopulationRig, np.random.Generator], Fault | None]] = {
    "mirrored": fault_mirrored,
    "units_mm": fault_units_mm,
    "scale_1pct": fault_scale_1pct,
    "spacing": fault_spacing,
    "offset_zero": fault_offset_zero,
    "offset_side": fault_offset_side,
    "swap_kinds": fault_swap_kinds,
    "swap_same": fault_swap_same,
    "board_swap": fault_board_swap,
}


def inject(rig: PopulationRig, fault: str) -> Fault | None:
    """The rig's data with ``fault`` injected (None when the rig cannot carry it, e.g. an
    offset fault on a rig without radars); seeded from the rig and the fault."""
    rng = np.random.default_rng([*rig.seed, 1 + FAULT_NAMES.index(fault)])
    return FAULTS[fault](rig, rng)


def true_unit_variances(rig: PopulationRig, units) -> np.ndarray:
    """(units,) the variance of every noise unit (:class:`rigcal.problem.noise.DetectionUnits`)
    as the rig's noise was drawn - also where the noise model cannot say it (an isotropic
    camera's depth noise does not grow with range; a radar's Cartesian noise is not angular)."""
    out = np.zeros(units.size)
    for u in range(units.size):
        name, comp = units.groups[units.group[u]]
        nz, scale = rig.noise[name], float(units.scale[u])
        if nz["model"] in ("isotropic", "cartesian"):
            out[u] = nz["sigma_m"] ** 2
        elif nz["model"] == "stereo":
            out[u] = nz["sigma_m"] ** 2 if comp == "lateral" else (nz["depth_sigma_at_1m_m"] * scale) ** 2
        elif comp == "range":
            out[u] = nz["range_sigma_m"] ** 2
        else:
            out[u] = (math.radians(nz[f"{comp}_sigma_deg"]) * scale) ** 2
    return out


#: the power a fault must be caught with on the rigs where a mode can see it (issue #20)
POWER = 0.95


def visible_std(sensors: int) -> float:
    """How many Cramer-Rao std of a sensor's scale a scale error must be for a mode to *see* it
    on a rig of ``sensors`` sensors: the verdict tests every sensor's scale at total level
    :data:`rigcal.problem.mistakes.ALPHA` (Bonferroni, critical value ``z``), so even the best
    estimator (the Cramer-Rao std) catches an error of ``d`` std with probability about
    ``Phi(d - z)``; :data:`POWER` needs ``d >= z + Phi^-1(POWER)`` (3.3 + 1.6 with one other
    sensor, 3.9 + 1.6 with eight). Fixed by the test's level and the power asked for, before any
    run."""
    from scipy.stats import norm

    from rigcal.problem.mistakes import ALPHA, z_critical

    return z_critical(ALPHA, sensors) + float(norm.ppf(POWER))


def scale_bound(rig: PopulationRig, name: str) -> float:
    """The Cramer-Rao std of sensor ``name``'s relative scale on ``rig``: the best linear
    unbiased estimate's std in the linearised model of every pair's residuals, at the true poses
    and with the true noise (:func:`rigcal.problem.mistakes.fit_efficient`). No estimator that
    knows only the detections does better; a 1 % scale below :func:`visible_std` of it cannot be
    caught with :data:`POWER` at the verdict's levels."""
    from rigcal.problem.consistency import pair_residuals
    from rigcal.problem.initialise import default_reference
    from rigcal.problem.mistakes import fit_efficient, scale_columns
    from rigcal.problem.noise import detection_units

    ds = rig.dataset
    ref = default_reference(ds)
    poses = {n: rig.sim.truth_T(ref, n) for n in ds.names}
    units = detection_units(ds)
    res = pair_residuals(ds, poses, ref, units, lambda names: np.zeros((6 * len(names),) * 2),
                         theta=np.full(len(units.groups), 1e-4))
    if res is None:
        return math.inf
    col = scale_columns(res).get(name)
    if col is None:
        return math.inf
    _, var, _ = fit_efficient(res, col[:, None], None, true_unit_variances(rig, units))
    return float(math.sqrt(var[0]))


# --------------------------------------------------------------------------------------------
# running


@dataclass(frozen=True)
class Run:
    """One calibration of the study: ``outcome`` ``consistent``, ``flagged``, ``undetermined``
    or ``refused`` (an error), the failed checks' names, the text of the failures (or the
    error), and for a MCPE run the flagged pairs the mode did not fit."""

    rig: int
    mode: str
    fault: str
    boards: int
    outcome: str
    failed: tuple[str, ...] = ()
    text: str = ""
    unfitted_pairs: tuple[str, ...] = ()
    named: bool = False
    radars: int = 0  # 2D and 3D radars of the rig
    visible: bool = True  # a 1 % scale: at least visible_std Cramer-Rao std (scale_bound)
    bound: float = math.nan  # that std (a 1 % scale fault), else NaN


def _outcome(result) -> str:
    return result.verdict.status if result.verdict is not None else "consistent"


def calibrate_run(dataset: Dataset, mode: str, options: dict | None = None):
    """``calibrate`` as the study runs it: (result or None, error text)."""
    from rigcal.problem.calibrate import CalibrationOptions, calibrate

    try:
        return calibrate(dataset, CalibrationOptions(mode=mode, **(options or {}))), ""
    except RigcalError as exc:
        return None, f"{type(exc).__name__}: {exc}"


def _unfitted(result, dataset: Dataset) -> tuple[str, ...]:
    """Pairs named in a failed ``pairs`` check that MCPE did not fit."""
    if result is None or result.mode != "mcpe":
        return ()
    pairs = next((c for c in result.verdict.failed if c.name == "pairs"), None)
    if pairs is None:
        return ()
    ref = result.reference
    return tuple(p for p in result.rmse_m if ref not in p.split("-") and p + " (" in pairs.detail)


#: what a verdict (or error) must say for each fault to count as named
NAMES = {
    "mirrored": lambda text, f: "mirrored" in text and f.sensors[0] in text,
    "units_mm": lambda text, f: "millimetres" in text and f.sensors[0] in text,
    "scale_1pct": lambda text, f: "scale" in text and f.sensors[0] in text,
    "spacing": lambda text, f: "spacing" in text,
    "offset_zero": lambda text, f: "reflector" in text and "offset" in text,
    "offset_side": lambda text, f: "reflector" in text,
    "swap_kinds": lambda text, f: "swapped" in text and all(s in text for s in f.sensors),
    "swap_same": lambda text, f: "swapped" in text and all(s in text for s in f.sensors),
    "board_swap": lambda text, f: f"board {f.options['board']}" in text and f.sensors[0] in text,
}


def _text(result, error: str) -> str:
    if result is None:
        return error
    parts = [f"{c.name}: {c.detail}" for c in result.verdict.checks if c.status != "pass"]
    parts += [f"outliers: {s} boards {list(b)}" for s, b in result.outliers.items()]
    return " | ".join(parts)


def run_rig(index: int, seed: int, modes: Sequence[str], faults: Sequence[str]) -> list[Run]:
    """Every mode on rig ``index``: clean, then with each fault."""
    rig = draw_rig(seed, index)
    out = []
    for fault in ("clean", *faults):
        f = None if fault == "clean" else inject(rig, fault)
        if fault != "clean" and f is None:
            continue
        dataset = rig.dataset if f is None else f.dataset
        opts = {} if f is None else {k: v for k, v in f.options.items() if k == "initial"}
        bound = scale_bound(rig, f.sensors[0]) if fault == "scale_1pct" else math.nan
        for mode in modes:
            result, error = calibrate_run(dataset, mode, opts)
            outcome = "refused" if result is None else _outcome(result)
            text = _text(result, error)
            named = False
            if f is not None:
                named = NAMES[fault](text, f)
                if fault == "board_swap" and result is not None:
                    # excluded as an outlier, or flagged, and the board named
                    excluded = f.options["board"] in result.outliers.get(f.sensors[0], ())
                    named = named or excluded
            out.append(Run(index, mode, fault, rig.num_boards, outcome,
                           tuple(c.name for c in result.verdict.failed) if result is not None else (),
                           text, _unfitted(result, dataset), named, len(_radars(rig.dataset)),
                           not bound > 0.01 / visible_std(len(dataset.sensors)), bound))
    return out


def detected(run: Run) -> bool:
    """A fault counts as caught when the run was flagged, refused or ended undetermined with
    the mistake named - or, for a board from another placement, that board excluded."""
    if run.fault == "board_swap":
        return run.named
    return run.outcome in ("flagged", "refused", "undetermined")


def summarise(runs: Sequence[Run], min_boards: int = 10) -> dict:
    """Per mode: the clean rigs' outcomes; per fault and mode: caught / named among rigs with at
    least ``min_boards`` boards."""
    modes = sorted({r.mode for r in runs}, key=["mcpe", "fcpe", "pse"].index)
    clean = {}
    for m in modes:
        rs = [r for r in runs if r.mode == m and r.fault == "clean"]
        n = len(rs)
        clean[m] = {
            "rigs": n,
            "flagged": sum(r.outcome == "flagged" for r in rs),
            "undetermined": sum(r.outcome == "undetermined" for r in rs),
            "refused": sum(r.outcome == "refused" for r in rs),
            "unfitted_pair_flags": sum(bool(r.unfitted_pairs) for r in rs),
            "checks": _count([c for r in rs for c in r.failed]),
        }
    faults = {}
    groups = [(f, f, lambda r: True) for f in FAULT_NAMES]
    # a single 2D radar's translation absorbs most of an offset: the offset faults also with
    # two or more radars
    groups += [(f"{f} (2+ radars)", f, lambda r: r.radars >= 2) for f in ("offset_zero", "offset_side")]
    # a 1 % scale also on the rigs where the modes can see it (visible_std)
    groups += [("scale_1pct (visible)", "scale_1pct", lambda r: r.visible)]
    for label, fault, among in groups:
        rows = {}
        for m in modes:
            rs = [r for r in runs if r.mode == m and r.fault == fault and r.boards >= min_boards and among(r)]
            if rs:
                rows[m] = {"rigs": len(rs), "caught": sum(detected(r) for r in rs),
                           "named": sum(r.named and detected(r) for r in rs)}
        if rows:
            faults[label] = rows
    return {"clean": clean, "faults": faults}


def _count(items) -> dict:
    out: dict = {}
    for i in items:
        out[i] = out.get(i, 0) + 1
    return out


__all__ = ["FAULTS", "FAULT_NAMES", "POWER", "Fault", "PopulationRig", "Run", "detected", "draw_rig", "visible_std",
           "inject", "run_rig", "scale_bound", "summarise", "three_radar_rig", "true_unit_variances"]
