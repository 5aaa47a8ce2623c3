"""Anderson acceleration of a fixed-point iteration x <- F(x) (Walker & Ni, SIAM J. Numer.
Anal. 49(4), 2011), with the safeguards the PSE noise loop needs: a damped base step, a cap on
each step and a restart from the best iterate when the residual grows."""

from __future__ import annotations

import numpy as np


class Anderson:
    """Feed it ``x`` and the residual ``F(x) - x``; it returns the next iterate.

    Immutable inputs: the arrays passed in are copied, never changed.
    """

    def __init__(self, window: int = 5, beta: float = 0.5, max_step: float = 1.0):
        self.window = window
        self.beta = beta
        self.max_step = max_step
        self._x: list[np.ndarray] = []
        self._g: list[np.ndarray] = []
        self._best: tuple[float, np.ndarray, np.ndarray] | None = None
        self._retreats = 0

    @property
    def retreat_step(self) -> float:
        return self.beta * 0.5**self._retreats

    @property
    def best(self) -> np.ndarray | None:
        """The iterate with the smallest residual so far."""
        return None if self._best is None else self._best[1].copy()

    def stuck(self, tol: float) -> bool:
        """True when steps from the best iterate have shrunk below ``tol`` without reducing
        its residual: F jumps there (a fixed point in the set-valued sense only)."""
        return self._best is not None and self._retreats > 0 and (
            self.retreat_step * float(np.max(np.abs(self._best[2]), initial=0.0)) < tol
        )

    def step(self, x: np.ndarray, g: np.ndarray) -> np.ndarray:
        x = np.array(x, dtype=float)
        g = np.array(g, dtype=float)
        norm = float(np.max(np.abs(g))) if g.size else 0.0
        if self._best is not None and norm >= self._best[0]:
            # no progress: forget the history, step from the best iterate, each time shorter
            # (across a jump of F the iterate so ends pinned at the jump: see ``stuck``)
            _, xb, gb = self._best
            self._x, self._g = [], []
            self._retreats += 1
            return xb + self.retreat_step * gb
        self._retreats = 0
        self._best = (norm, x, g)
        self._x.append(x)
        self._g.append(g)
        self._x = self._x[-(self.window + 1):]
        self._g = self._g[-(self.window + 1):]
        new = x + self.beta * g
        if len(self._x) > 1:
            dX = np.diff(np.array(self._x), axis=0).T
            dG = np.diff(np.array(self._g), axis=0).T
            gamma = np.linalg.lstsq(dG, g, rcond=1e-10)[0]
            new = new - (dX + self.beta * dG) @ gamma
        d = new - x
        big = float(np.max(np.abs(d))) if d.size else 0.0
        if big > self.max_step:
            d = d * (self.max_step / big)
        return x + d
