"""The verdict study's bookkeeping: which rigs a mode can see a 1 % scale on, and the summary."""

from __future__ import annotations

import pytest
from scipy.stats import norm

from rigcal.problem.mistakes import ALPHA, z_critical
from rigcal.study.verdict import POWER, Run, summarise, visible_std


def test_visible_std_is_the_test_level_plus_the_power_asked_for():
    # one test at 1e-3 two-sided: 3.29; 95 % power: 1.64 more
    assert visible_std(1) == pytest.approx(3.2905 + 1.6449, abs=1e-3)
    for n in (2, 4, 8):
        assert visible_std(n) == pytest.approx(z_critical(ALPHA, n) + norm.ppf(POWER))
    assert visible_std(2) < visible_std(8)


def test_the_visible_scale_row_counts_only_the_rigs_a_mode_can_see_the_fault_on():
    runs = [Run(0, "fcpe", "scale_1pct", 12, "flagged", visible=True, bound=0.001),
            Run(1, "fcpe", "scale_1pct", 12, "consistent", visible=False, bound=0.0027),
            Run(2, "fcpe", "scale_1pct", 12, "consistent", visible=True, bound=0.0015),
            Run(3, "fcpe", "scale_1pct", 8, "flagged", visible=True, bound=0.001),  # < 10 boards
            Run(0, "fcpe", "clean", 12, "consistent")]
    s = summarise(runs)
    assert s["faults"]["scale_1pct"]["fcpe"] == {"rigs": 3, "caught": 1, "named": 0}
    assert s["faults"]["scale_1pct (visible)"]["fcpe"] == {"rigs": 2, "caught": 1, "named": 0}
    assert s["clean"]["fcpe"]["rigs"] == 1 and s["clean"]["fcpe"]["flagged"] == 0
