"""Can the boards determine every sensor's pose? Checked before solving, so that a refusal says
what is missing ("radar1 shares only 2 boards with lidar1") instead of a solver failing on a
singular problem.

Per sensor, from the boards it shares with sensors already determined (starting from the
reference): a lidar or camera needs one shared board (four circle centres); a 3D radar three
reflectors not on one line; a 2D radar three reflectors not on one line in its plane (range and
azimuth give two equations per board for six unknowns), or two distinct reflectors when its z,
roll and pitch are held. MCPE solves each sensor against the reference alone, so there only
the boards shared with the reference count.
"""

from __future__ import annotations

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import GeometryError
from rigcal.problem.pairs import PairData, all_pairs, pair_data

#: reflectors whose rms distance from their best-fit line is below this are collinear [m]
COLLINEAR_M = 0.005


def _spread(points: np.ndarray) -> tuple[float, float]:
    """rms distance of points from their centroid along the first and second principal axes."""
    if len(points) < 2:
        return 0.0, 0.0
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False) / np.sqrt(len(points))
    return float(s[0]), float(s[1]) if s.size > 1 else 0.0


def _own_points(pair: PairData, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Per shared board, the anchor as ``name`` sees it (its measurement if it is the observer,
    else the point in its frame): (boards, (k, d) points)."""
    pts = pair.measured if pair.observer == name else pair.points
    boards = pair.boards
    return boards, np.stack([pts[pair.board == b].mean(axis=0) for b in boards])


def _verdict(
    name: str, kind: SensorKind, shared: dict[str, PairData], hold_plane: bool, candidates: list[str]
) -> str | None:
    """None if the pairs in ``shared`` (partner -> pair data) determine ``name``, else why not."""
    if kind in (SensorKind.LIDAR, SensorKind.CAMERA) and any(
        p.per_board == 4 and p.num_boards for p in shared.values()
    ):
        return None  # the four circle centres of one board fix a pose
    # otherwise one reflector per board: 3 not on one line (2 distinct with the plane held)
    need = 2 if hold_plane else 3
    by_board: dict[int, list[np.ndarray]] = {}
    for pair in shared.values():
        boards, pts = _own_points(pair, name)
        for b, p in zip(boards, pts):
            by_board.setdefault(int(b), []).append(p)
    n = len(by_board)
    partners = " or ".join(shared or candidates)
    if kind == SensorKind.RADAR:
        rule = "a 2D radar needs " + (
            "2 distinct boards with its plane held" if hold_plane else "3 boards not on one line"
        )
    elif kind == SensorKind.RADAR3D:
        rule = "a 3D radar needs 3 boards not on one line"
    else:
        rule = f"{name} needs 1 board seen by a lidar or camera, or 3 reflectors not on one line"
    if n < need:
        detail = ", ".join(f"{shared[t].num_boards} with {t}" for t in shared)
        only = "no boards" if n == 0 else f"only {n} board{'s' if n > 1 else ''}"
        detail = f" ({detail})" if len(shared) > 1 else ""
        return f"{name} shares {only} with {partners}{detail}; {rule}"
    pts = np.stack([np.mean(v, axis=0) for v in by_board.values()])
    first, second = _spread(pts)
    if need == 2 and first < COLLINEAR_M:
        return f"the {n} boards {name} shares with {partners} are at one spot in {name}; {rule}"
    if need == 3 and second < COLLINEAR_M:
        return (
            f"the {n} boards {name} shares with {partners} are collinear in {name} (within "
            f"{second * 1000:.1f} mm of one line); {rule}"
        )
    return None


def check_observable(
    dataset: Dataset, mode: str, reference: str, hold_radar_plane: bool = False
) -> None:
    """Raise GeometryError naming each sensor the boards cannot determine, and why."""
    pairs = {}
    for a, b in all_pairs(dataset):
        p = pair_data(dataset, a, b)
        if p is not None and p.num_boards:
            pairs[(a, b)] = pairs[(b, a)] = p
    kinds = {s.name: s.kind for s in dataset.sensors}
    known = {reference}
    problems: dict[str, str] = {}
    pending = [s for s in dataset.names if s != reference]
    changed = True
    while changed and pending:
        changed = False
        for name in list(pending):
            partners = [reference] if mode == "mcpe" else sorted(known, key=dataset.names.index)
            shared = {t: pairs[(name, t)] for t in partners if (name, t) in pairs}
            why = _verdict(
                name, kinds[name], shared, hold_radar_plane and kinds[name] == SensorKind.RADAR, partners
            )
            if why is None:
                known.add(name)
                pending.remove(name)
                problems.pop(name, None)
                changed = True
            else:
                problems[name] = why
    if pending:
        alone = " (MCPE compares each sensor with the reference alone)" if mode == "mcpe" else ""
        raise GeometryError(
            "the boards cannot determine every pose: " + "; ".join(problems[s] for s in pending) + alone
        )


__all__ = ["COLLINEAR_M", "check_observable"]
