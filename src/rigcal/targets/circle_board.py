"""The circle board (Domhof et al. 2021): four holes on a square, a corner reflector behind.

Board frame: origin at the centre of the four holes on the front face, x to the right and
y up as seen by a sensor in front of the board, z out of the front face (toward the sensors).
Hole centres in order top-left, top-right, bottom-left, bottom-right:
(-s/2, s/2, 0), (s/2, s/2, 0), (-s/2, -s/2, 0), (s/2, -s/2, 0) with s = spacing_m.
The reflector's phase centre sits ``reflector_offset_m`` behind the front face: (0, 0, -offset).
"""

from __future__ import annotations

import numpy as np

from rigcal.dataset import BoardGeometry


def board_centres(board: BoardGeometry) -> np.ndarray:
    """(4, 3) hole centres in the board frame [m], order TL, TR, BL, BR."""
    h = board.spacing_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [-h, -h, 0.0], [h, -h, 0.0]])


def reflector_in_board(board: BoardGeometry) -> np.ndarray:
    """(3,) reflector position in the board frame [m]."""
    return np.array([0.0, 0.0, -board.reflector_offset_m])


def board_normals(centres_sensor: np.ndarray) -> np.ndarray:
    """Unit normals (K, 3) of boards given their centres (K, 4, 3) in a sensor frame.

    The normal is the least-squares plane normal of the four centres, oriented away from the
    sensor (positive dot product with the centroid), i.e. pointing from the front face to the back.
    Boards with any non-finite centre (missed detections) get NaN normals.
    """
    c = np.asarray(centres_sensor, dtype=float)
    out = np.full((c.shape[0], 3), np.nan)
    ok = np.all(np.isfinite(c.reshape(c.shape[0], -1)), axis=1)  # missed boards stay NaN
    if not np.any(ok):
        return out
    cc = c[ok]
    mean = cc.mean(axis=1, keepdims=True)
    _, _, Vt = np.linalg.svd(cc - mean)
    n = Vt[:, 2, :]
    flip = np.einsum("ki,ki->k", n, mean[:, 0, :]) < 0
    out[ok] = np.where(flip[:, None], -n, n)
    return out


def reflectors_from_centres(centres_sensor: np.ndarray, board: BoardGeometry) -> np.ndarray:
    """Reflector positions (K, 3) in the sensor frame from hole centres (K, 4, 3) (paper's g)."""
    c = np.asarray(centres_sensor, dtype=float)
    return c.mean(axis=1) + board.reflector_offset_m * board_normals(c)


def square_error_m(centres_sensor: np.ndarray, board: BoardGeometry) -> np.ndarray:
    """(K,) largest deviation [m] of the four sides and two diagonals from the board's square."""
    c = np.asarray(centres_sensor, dtype=float)
    s = board.spacing_m
    pairs = [(0, 1, s), (2, 3, s), (0, 2, s), (1, 3, s), (0, 3, s * np.sqrt(2)), (1, 2, s * np.sqrt(2))]
    errs = [np.abs(np.linalg.norm(c[:, i] - c[:, j], axis=-1) - d) for i, j, d in pairs]
    return np.max(np.stack(errs, axis=1), axis=1)
