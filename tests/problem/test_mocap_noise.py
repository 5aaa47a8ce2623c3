"""The variance components of motion-capture residuals (REML), on residuals drawn from known ones."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.problem.mocap_noise import (Components, NoiseCovariance, effective_dof, fit_components, fit_shared, gls, sandwich,
                                        weighting_test, widening)


def _design(rng, holds=8, frames=6, points=40):
    """Rows of ``holds`` x ``frames`` frames of ``points`` 2-D points each: fixed effects X
    (n, 6), per-frame loadings (6 each), per-hold loadings (3 each) and view groups (one per
    point coordinate and hold)."""
    n_f = holds * frames
    n = n_f * points * 2
    X = rng.normal(size=(n, 6))
    frame = np.repeat(np.arange(n_f), points * 2)
    hold = frame // frames
    cap = np.zeros((n, 6 * n_f))
    hld = np.zeros((n, 3 * holds))
    base = rng.normal(size=(holds, points * 2, 3))
    for f in range(n_f):
        rows = frame == f
        cap[rows, 6 * f: 6 * f + 6] = rng.normal(size=(rows.sum(), 6)) * 0.3
        g = f // frames
        hld[rows, 3 * g: 3 * g + 3] = base[g]
    groups = hold * points * 2 + np.tile(np.arange(points * 2), n_f)
    return X, {"capture": cap, "hold": hld}, groups


def _draw(rng, X, loads, groups, s2, cap, hold, view):
    n = X.shape[0]
    r = X @ rng.normal(size=6) + rng.normal(0, np.sqrt(s2), n)
    r += loads["capture"] @ rng.normal(0, np.sqrt(cap), loads["capture"].shape[1])
    r += loads["hold"] @ rng.normal(0, np.sqrt(hold), loads["hold"].shape[1])
    r += rng.normal(0, np.sqrt(view), groups.max() + 1)[groups]
    return r


def test_components_are_recovered_from_residuals_that_have_them():
    rng = np.random.default_rng(0)
    X, loads, groups = _design(rng)
    r = _draw(rng, X, loads, groups, s2=1.0, cap=4.0, hold=9.0, view=0.5)
    c = fit_components(r, X, loads, groups=groups)
    assert c.s2 == pytest.approx(1.0, rel=0.1)
    assert c.get("capture") == pytest.approx(4.0, rel=0.35)
    assert c.get("hold") == pytest.approx(9.0, rel=0.8)  # 8 holds: few groups
    assert c.get("view") == pytest.approx(0.5, rel=0.3)
    assert 2 < c.dof["hold"] < 60 and c.dof["capture"] > c.dof["hold"]


def test_components_the_residuals_do_not_need_are_dropped():
    # point noise alone: no spurious hold error (it would widen the covariance for nothing)
    rng = np.random.default_rng(1)
    X, loads, groups = _design(rng, holds=4)
    r = _draw(rng, X, loads, groups, s2=2.0, cap=0.0, hold=0.0, view=0.0)
    c = fit_components(r, X, loads, groups=groups)
    assert c.s2 == pytest.approx(2.0, rel=0.1)
    assert c.get("hold") == 0.0  # few groups: dropped
    # many groups: zero is replaced by the largest value the data do not exclude, a tight bound
    assert 0 < c.get("view") < 0.05 * c.s2 and c.dof["view"] == np.inf
    assert c.get("capture") == 0.0


def test_a_floor_is_a_known_least_value_not_an_estimate():
    rng = np.random.default_rng(2)
    X, loads, groups = _design(rng, holds=4)
    r = _draw(rng, X, loads, groups, s2=1.0, cap=0.0, hold=0.0, view=0.0)
    c = fit_components(r, X, loads, floors={"capture": 3.0})
    assert c.get("capture") == 3.0 and c.floored["capture"] and c.dof["capture"] == np.inf


def test_a_fixed_component_is_held_and_its_cost_is_the_deviance_difference():
    rng = np.random.default_rng(21)
    X, loads, groups = _design(rng, holds=4)
    r = _draw(rng, X, loads, groups, s2=1.0, cap=0.0, hold=9.0, view=0.0)
    free = fit_components(r, X, loads)
    held = fit_components(r, X, loads, fixed={"hold": (9.0, 12.0)})
    assert held.get("hold") == 9.0 and held.dof["hold"] == 12.0 and held.fixed == {"hold"}
    assert free.fixed == frozenset() and held.deviance >= free.deviance - 1e-6
    # a value the residuals exclude costs far more than the likelihood test's level
    wrong = fit_components(r, X, loads, fixed={"hold": (1e-4, 12.0)})
    assert wrong.deviance - free.deviance > 10.0


def _sensors(rng, n, holds, hold, s2=1.0):
    out = []
    for _ in range(n):
        X, loads, groups = _design(rng, holds=holds, frames=3, points=10)
        loads = {"hold": loads["hold"]}
        r = X @ rng.normal(size=6) + rng.normal(0, np.sqrt(s2), len(X))
        r += loads["hold"] @ rng.normal(0, np.sqrt(hold), loads["hold"].shape[1])
        out.append({"r": r, "X": X, "loadings": loads})
    return out


def test_a_per_hold_error_common_to_the_sensors_is_estimated_from_all_their_holds():
    """Four holds each: one sensor's estimate rests on a few degrees of freedom (or is dropped),
    the pooled one on all the sensors' holds together."""
    rng = np.random.default_rng(22)
    sensors = _sensors(rng, 4, holds=4, hold=4.0)
    shared = fit_shared(sensors, names=("hold",))
    own = [fit_components(s["r"], s["X"], s["loadings"]) for s in sensors]
    assert shared.values["hold"] == pytest.approx(4.0, rel=0.6)
    assert shared.dof["hold"] > max(o.dof["hold"] for o in own if o.get("hold") > 0)
    assert shared.gain > 2.71 and shared.kept() == {"hold": (shared.values["hold"], shared.dof["hold"])}
    # the sensors' own noise is each its own: a sensor twice as noisy keeps its s2
    noisy = _sensors(rng, 1, holds=4, hold=4.0, s2=4.0)
    both = fit_shared(sensors[:2] + noisy, names=("hold",))
    assert both.values["hold"] == pytest.approx(4.0, rel=0.8)


def test_no_common_per_hold_error_none_is_kept_and_one_sensor_is_not_pooled():
    rng = np.random.default_rng(23)
    kept = [fit_shared(_sensors(rng, 3, holds=4, hold=0.0), names=("hold",)).kept() for _ in range(10)]
    assert sum(bool(k) for k in kept) <= 2  # the test's level: about 1 in 10 (two-sided boundary)
    alone = fit_shared(_sensors(rng, 1, holds=4, hold=4.0), names=("hold",))
    assert alone.values == {"hold": 0.0} and alone.gain == 0.0


def test_sandwich_parts_add_up_and_the_prior_bounds_an_undetermined_effect():
    rng = np.random.default_rng(3)
    X, loads, groups = _design(rng, holds=4, frames=2, points=10)
    comp = Components(s2=1.0, values={"capture": 0.5, "hold": 2.0}, dof={"hold": 5.0}, floored={})
    parts = sandwich(X, loads, comp)
    assert set(parts) == {"point", "capture", "hold"}
    for p in parts.values():
        assert np.all(np.linalg.eigvalsh(p) > -1e-12)
    # a seventh fixed effect equal to the first: only its prior tells them apart, and the
    # covariance of the first grows by what the prior allows
    X7 = np.column_stack([X, X[:, 0]])
    cov7 = sum(sandwich(X7, loads, comp, prior=np.r_[np.zeros(6), 1.0 / 0.1]).values())
    cov6 = sum(parts.values())
    assert cov7[6, 6] == pytest.approx(0.01, rel=0.05)
    assert cov7[0, 0] == pytest.approx(cov6[0, 0] + 0.01, rel=0.05)


def _dense_v(n, loads, comp, groups=None, known=None):
    known = np.zeros(n, dtype=bool) if known is None else known
    V = np.diag(np.where(known, 1.0, comp.s2))
    for c, U in loads.items():
        if c != "view_pose":
            V += comp.get(c) * U @ U.T
    if groups is not None and comp.get("view") > 0:
        Z = np.zeros((n, groups.max() + 1))
        Z[np.flatnonzero(groups >= 0), groups[groups >= 0]] = 1.0
        V += comp.get("view") * Z @ Z.T
        if "view_pose" in loads:
            V -= comp.get("view") * loads["view_pose"] @ loads["view_pose"].T
    return V


def _dense_lambda(V, X, C, loads, comp, groups, known, W):
    """2 C [sum_ab W_ab (Q_ab - P_a C P_b)] C with every source's share of V formed."""
    n = len(X)
    share = {"point": np.diag(np.where(known, 0.0, comp.s2))}
    for c in ("capture", "hold"):
        share[c] = comp.get(c) * loads[c] @ loads[c].T
    Z = np.zeros((n, groups.max() + 1))
    Z[np.flatnonzero(groups >= 0), groups[groups >= 0]] = 1.0
    share["view"] = comp.get("view") * (Z @ Z.T - loads["view_pose"] @ loads["view_pose"].T)
    Vi = np.linalg.inv(V)
    inner = np.zeros((X.shape[1],) * 2)
    for (a, b), w in W.items():
        Pa = -X.T @ Vi @ share[a] @ Vi @ X
        Pb = -X.T @ Vi @ share[b] @ Vi @ X
        Q = X.T @ Vi @ share[a] @ Vi @ share[b] @ Vi @ X
        inner += w * (Q - Pa @ C @ Pb)
    return 2.0 * C @ (0.5 * (inner + inner.T)) @ C


def test_gls_step_and_parts_are_the_dense_generalised_least_squares():
    """The step from the current fixed effects to the GLS estimate (with the prior's pull on a
    seventh effect), and its covariance split by source, against V formed and inverted."""
    rng = np.random.default_rng(31)
    X, loads, groups = _design(rng, holds=3, frames=2, points=6)
    n = len(X)
    known = np.zeros(n, dtype=bool)
    known[-10:] = True  # rows of known unit variance, in no view group
    groups = np.where(known, -1, groups)
    loads = {**loads, "view_pose": 0.05 * rng.normal(size=(n, 3))}
    comp = Components(s2=0.7, values={"capture": 0.5, "hold": 2.0, "view": 0.3}, dof={"hold": 5.0}, floored={})
    X7 = np.column_stack([X, rng.normal(size=n)])
    prior, mean = np.r_[np.zeros(6), 1.0 / 0.2], np.r_[np.zeros(6), 0.05]
    r = rng.normal(size=n)
    step, parts = gls(r, X7, loads, comp, prior, mean, groups, known)
    V = _dense_v(n, loads, comp, groups, known)
    assert np.all(np.linalg.eigvalsh(V) > 0)
    Vi = np.linalg.inv(V)
    P = np.diag(prior ** 2)
    C = np.linalg.inv(X7.T @ Vi @ X7 + P)
    assert step == pytest.approx(-C @ (X7.T @ Vi @ r + P @ mean), rel=1e-8, abs=1e-12)
    assert set(parts) == {"point", "known", "capture", "hold", "view", "prior", "weights"}
    assert sum(v for k, v in parts.items() if k != "weights") == pytest.approx(C, rel=1e-8, abs=1e-14)
    H = Vi @ X7 @ C
    U = loads["hold"]
    assert parts["hold"] == pytest.approx(2.0 * H.T @ U @ U.T @ H, rel=1e-8, abs=1e-14)
    # the weights' uncertainty (Kenward-Roger's 2 Lambda) from each source's share of V and the
    # covariance of the variances' logs: here only the hold's, 2 / dof
    assert parts["weights"] == pytest.approx(_dense_lambda(V, X7, C, loads, comp, groups, known,
                                                           {("hold", "hold"): 2.0 / 5.0}), rel=1e-6, abs=1e-14)
    # with the components' correlations (REML's log_cov), crossing terms count
    lc = {("point", "point"): 0.01, ("hold", "hold"): 0.3, ("capture", "capture"): 0.1,
          ("point", "hold"): -0.02, ("hold", "point"): -0.02, ("view", "view"): 0.05}
    comp2 = Components(s2=0.7, values=comp.values, dof={"hold": 5.0}, floored={}, log_cov=lc)
    _, parts2 = gls(r, X7, loads, comp2, prior, mean, groups, known)
    assert parts2["weights"] == pytest.approx(_dense_lambda(V, X7, C, loads, comp2, groups, known, lc),
                                              rel=1e-6, abs=1e-14)
    assert np.all(np.linalg.eigvalsh(parts2["weights"]) > -1e-12) and np.trace(parts2["weights"]) > 0
    # the weighted estimate is the better one: least squares (every row alike) scatters more
    ls = sum(sandwich(X7, loads, comp, prior, groups, known).values())
    assert np.all(np.linalg.eigvalsh(ls - C) > -1e-12) and np.trace(ls) > 1.05 * np.trace(C)


def _huber(c):
    return lambda u2: np.where(u2 <= c * c, 1.0, c / np.sqrt(np.maximum(u2, 1e-300)))


def test_gls_weighs_down_an_outlier_by_its_std_under_the_noise_model_not_a_modelled_hold_error():
    rng = np.random.default_rng(34)
    X, loads, groups = _design(rng, holds=6, frames=3, points=8)
    loads = {"hold": loads["hold"]}
    comp = Components(s2=1.0, values={"hold": 4.0}, dof={}, floored={})
    n = len(X)
    L = np.linalg.cholesky(_dense_v(n, loads, comp))
    r = L @ rng.normal(size=n)  # per-hold errors of several point sigmas: modelled, not outliers
    plain, _ = gls(r, X, loads, comp)
    assert gls(r, X, loads, comp, robust=_huber(3.0))[0] == pytest.approx(plain, rel=0.05, abs=1e-9)
    # a huber loss on the point noise alone would call many of them outliers
    assert np.mean(np.abs(r) > 3.0) > 0.05
    bad = r.copy()
    bad[:5] += 200.0  # five wild rows
    pulled = gls(bad, X, loads, comp)[0]
    held = gls(bad, X, loads, comp, robust=_huber(3.0))[0]
    assert np.linalg.norm(held - plain) < 0.2 * np.linalg.norm(pulled - plain)


def test_the_weighting_test_passes_residuals_of_the_model_and_rejects_an_error_it_lacks():
    from scipy.stats import chi2

    rng = np.random.default_rng(35)
    X, loads, groups = _design(rng, holds=6, frames=3, points=8)
    loads = {"hold": loads["hold"] * np.linspace(0.2, 3.0, len(X))[:, None]}
    comp = Components(s2=1.0, values={"hold": 4.0}, dof={}, floored={})
    n = len(X)
    L = np.linalg.cholesky(_dense_v(n, loads, comp))
    vcov = NoiseCovariance(loads, comp, None, None, n)
    ls_cov = sum(sandwich(X, loads, comp).values())

    def stat(r):
        r = r - X @ np.linalg.lstsq(X, r, rcond=None)[0]  # at the least-squares solution
        step, parts = gls(r, X, loads, comp, vcov=vcov)
        return weighting_test(step, ls_cov, sum(parts.values()))

    stats = [stat(L @ rng.normal(size=n)) for _ in range(300)]
    dof = {d for _, d in stats}
    assert dof == {6}
    level = chi2.ppf(0.99, 6)
    assert np.mean([t > level for t, _ in stats]) < 0.04  # 1 % expected
    assert np.mean([t for t, _ in stats]) == pytest.approx(6.0, abs=0.8)
    # one hold's error far beyond the per-hold variance the model has (a bad hold): weighted
    # by the model it is taken for that hold's error, least squares takes it into the pose
    U = loads["hold"]
    bad = L @ rng.normal(size=n) + 25.0 * np.sqrt(4.0) * U[:, :3] @ np.ones(3)
    assert stat(bad)[0] > 2 * level, stat(bad)


def test_gls_estimate_scatters_as_its_covariance_says_and_apart_from_the_noise_estimate():
    """Residuals drawn from the model (per-hold errors dominating): over many draws the GLS
    estimate scatters as its covariance says, and - unlike the least-squares estimate - its
    error is uncorrelated with the residual contrasts the noise is estimated from (the size of
    the per-hold error seen in the residuals)."""
    rng = np.random.default_rng(32)
    X, loads, groups = _design(rng, holds=6, frames=3, points=8)
    loads = {"hold": loads["hold"] * np.linspace(0.2, 3.0, len(X))[:, None]}  # unequal holds
    comp = Components(s2=1.0, values={"hold": 25.0}, dof={}, floored={})
    n = len(X)
    V = _dense_v(n, loads, comp)
    L = np.linalg.cholesky(V)
    Q, _ = np.linalg.qr(X)
    est_g, est_l, contrast = [], [], []
    for _ in range(1000):
        e = L @ rng.normal(size=n)
        step, parts = gls(e, X, loads, comp)
        est_g.append(step)
        est_l.append(-np.linalg.lstsq(X, e, rcond=None)[0])
        res = e - Q @ (Q.T @ e)
        contrast.append(float(res @ res))
    est_g, est_l, contrast = map(np.asarray, (est_g, est_l, contrast))
    C = sum(v for k, v in parts.items() if k != "weights")  # the weights known here
    size_g = np.einsum("ij,jk,ik->i", est_g, np.linalg.inv(C), est_g)
    ls_cov = sum(sandwich(X, loads, comp).values())
    size_l = np.einsum("ij,jk,ik->i", est_l, np.linalg.inv(ls_cov), est_l)
    corr_g = np.corrcoef(size_g, contrast)[0, 1]
    corr_l = np.corrcoef(size_l, contrast)[0, 1]
    # the mean of a chi-square with 6 dof over 1000 draws: 6 +- 0.11
    assert np.mean(size_g) == pytest.approx(6.0, abs=0.4), np.mean(size_g)
    assert abs(corr_g) < 0.15 < corr_l, (corr_g, corr_l)


def test_widening_and_effective_degrees_of_freedom():
    assert widening(np.inf) == 1.0 and widening(0.0) == 1.0
    assert widening(3.0) > widening(10.0) > widening(100.0) > 1.0
    assert widening(1e5) == pytest.approx(1.0, abs=0.01)
    C = np.eye(6)
    comp = Components(s2=1.0, values={}, dof={"point": 1000.0, "hold": 4.0}, floored={})
    # the hold part dominates: its few degrees of freedom are the covariance's
    assert effective_dof({"point": 0.01 * C, "hold": C}, comp) == pytest.approx(4.0, rel=0.05)
    # a negligible uncertain part does not matter
    assert effective_dof({"point": C, "hold": 1e-6 * C}, comp) > 500


def _dense_reml(r, X, V):
    """-2 log REML written out densely: log|V| + log|X' V^-1 X| + r' P r."""
    Vi = np.linalg.inv(V)
    Q = np.linalg.svd(X, full_matrices=False)[0]
    A = Q.T @ Vi @ Q
    P = Vi - Vi @ Q @ np.linalg.solve(A, Q.T @ Vi)
    return np.linalg.slogdet(V)[1] + np.linalg.slogdet(A)[1] + float(r @ P @ r)


def _matches_dense(f, phi, r, X, V) -> bool:
    """``f(phi)`` is the dense -2 log REML where ``V`` is a covariance (True) and refused
    (1e300) where it is not (False)."""
    if np.linalg.eigvalsh(V).min() > 0:
        assert f(phi) == pytest.approx(_dense_reml(r, X, V), rel=1e-8, abs=1e-6)
        return True
    assert f(phi) == 1e300
    return False


@pytest.mark.parametrize("with_hold", [True, False])
def test_reml_is_the_dense_likelihood_where_v_is_a_covariance_and_refused_elsewhere(with_hold):
    """The view component's pose part enters with a negative sign, so V = s2 I + view (Z Z' -
    W W') + ... is a covariance only for some parameters. Where it is not, the Woodbury form
    gave finite, hugely negative values (-3e11 on a camera of the mocap demo) that the search
    took: a point noise of 1e-11 and a 2.5 m std. It must refuse exactly there."""
    from rigcal.problem.mocap_noise import _Reml

    rng = np.random.default_rng(5)
    n = 24
    groups = np.repeat(np.arange(12), 2)
    X = rng.normal(size=(n, 2))
    hold = rng.normal(size=(n, 3))
    W = np.zeros((n, 1))
    W[:2, 0] = 1.5  # more than the group's own loading: V indefinite for a large view
    r = rng.normal(size=n)
    if not with_hold:  # the view's pose part the only low-rank effect
        hold = np.zeros((n, 0))
    f = _Reml(r, X, {"hold": hold, "view_pose": W}, groups)
    Z = np.zeros((n, 12))
    Z[np.arange(n), groups] = 1.0
    refused = accepted = 0
    for log_s2 in (-6.0, -2.0, 0.0):
        for log_hold in (-4.0, 0.0):
            for log_view in (-6.0, -1.0, 0.0, 2.0):
                phi = np.array([log_s2, log_hold, log_view] if with_hold else [log_s2, log_view])
                s2, th = f.theta(phi)
                V = s2 * np.eye(n) + th[-1] * (Z @ Z.T - W @ W.T)
                if with_hold:
                    V = V + th[0] * hold @ hold.T
                if _matches_dense(f, phi, r, X, V):
                    accepted += 1
                else:
                    refused += 1
    assert refused and accepted  # both sides were tried


@pytest.mark.parametrize("frames_per_hold", [(2, 2, 2), (2, 3, 2, 1)])
def test_independent_holds_are_factored_block_by_block_with_the_same_likelihood(frames_per_hold):
    """Effects that share no row (one hold's capture, hold and view errors, not another's) make
    N block diagonal; it is factored per block (a 15-hold session's noise fit 2.5x faster), the
    blocks of one shape as one stack (holds with as many frames). The likelihood is the dense
    one, and a block without a positive definite V is refused."""
    from rigcal.problem.mocap_noise import _Reml

    rng = np.random.default_rng(8)
    holds, pts = len(frames_per_hold), 4
    hold_of_frame = np.repeat(np.arange(holds), frames_per_hold)
    frames = len(hold_of_frame)
    n = frames * pts
    frame = np.repeat(np.arange(frames), pts)
    hold = hold_of_frame[frame]
    groups = hold * pts + np.tile(np.arange(pts), frames)  # a point in every frame of its hold
    X = rng.normal(size=(n, 2))
    cap = np.zeros((n, 2 * frames))
    hld = np.zeros((n, 2 * holds))
    W = np.zeros((n, holds))
    for f in range(frames):
        cap[frame == f, 2 * f:2 * f + 2] = rng.normal(size=(pts, 2))
    for h in range(holds):
        hld[hold == h, 2 * h:2 * h + 2] = rng.normal(size=(frames_per_hold[h] * pts, 2))
        W[hold == h, h] = np.tile(rng.normal(size=pts), frames_per_hold[h]) * 0.6
    known = np.zeros(n, dtype=bool)
    known[frame == 1] = True  # rows of known variance, in a view group of none
    groups = np.where(known, -1, groups)
    r = rng.normal(size=n)
    f = _Reml(r, X, {"capture": cap, "hold": hld, "view_pose": W}, groups, known)
    assert len(f.blocks) == holds
    assert len(f.stacks) == len(set(frames_per_hold))  # one stack per block shape
    assert sum(len(st.idx) for st in f.stacks) == holds
    Z = np.zeros((n, groups.max() + 1))
    Z[np.flatnonzero(groups >= 0), groups[groups >= 0]] = 1.0
    refused = accepted = 0
    for phi in ([0.0, -1.0, 0.5, -2.0], [-1.0, 0.0, -3.0, 0.0], [0.5, 1.0, 1.0, 1.0], [-4.0, -2.0, -2.0, 3.0]):
        phi = np.array(phi)
        s2, th = f.theta(phi)
        V = (np.diag(np.where(known, 1.0, s2)) + th[0] * cap @ cap.T + th[1] * hld @ hld.T
             + th[2] * (Z @ Z.T - W @ W.T))
        if _matches_dense(f, phi, r, X, V):
            accepted += 1
        else:
            refused += 1
    assert refused and accepted


def test_two_shapes_of_one_per_hold_error_are_tested_as_a_family():
    """Issue 23: two components that model the same per-hold error in different shapes (an
    isotropic pose error, a camera's affine error of its grid) each cost little to drop while
    the other takes over; dropped one after the other, a per-hold error the residuals show
    (its single component is kept) went unmodelled - a camera refit from a coverage session
    came out with NEES6 213. As a family, the last one is tested against the deviance before
    any of them was dropped."""
    rng = np.random.default_rng(1)
    holds, rows = 4, 40
    n = holds * rows
    X = rng.normal(size=(n, 3))
    base = rng.normal(size=(rows, 3))
    iso, shaped = np.zeros((n, 3 * holds)), np.zeros((n, 3 * holds))
    for h in range(holds):
        iso[h * rows:(h + 1) * rows, 3 * h:3 * h + 3] = base
        shaped[h * rows:(h + 1) * rows, 3 * h:3 * h + 3] = base @ np.diag([1.0, 0.3, 3.0])
    r = rng.normal(size=n) + iso @ rng.normal(0, 0.15, 3 * holds)
    r = r - X @ np.linalg.lstsq(X, r, rcond=None)[0]
    alone = fit_components(r, X, {"hold_rot": iso})
    assert alone.get("hold_rot") > 0  # the residuals need a per-hold error
    both = fit_components(r, X, {"hold_rot": iso, "hold": shaped})
    assert both.get("hold_rot") + both.get("hold") > 0


@pytest.mark.parametrize("shared", [0.0, 0.5])
def test_rows_of_known_variance_keep_it_and_share_only_the_random_effects(shared):
    """A lidar's ring ends: rows whose own variance is known (1) next to points whose noise is
    estimated (s2 = 4, told 1), with an error shared by the ends of one group (a frame's side of
    the plate) of variance ``shared``: s2 comes from the points alone, the shared error is found
    when it is there and dropped when it is not, and the sandwich weights the known rows by 1."""
    rng = np.random.default_rng(11)
    n_pts, groups_n, per = 3000, 60, 6
    n = n_pts + groups_n * per
    known = np.zeros(n, dtype=bool)
    known[n_pts:] = True
    X = rng.normal(size=(n, 6))
    g = np.repeat(np.arange(groups_n), per)
    U = np.zeros((n, groups_n))
    U[n_pts + np.arange(groups_n * per), g] = 1.0
    r = X @ rng.normal(size=6)
    r[:n_pts] += rng.normal(0, 2.0, n_pts)
    r[n_pts:] += rng.normal(0, 1.0, groups_n * per) + rng.normal(0, np.sqrt(shared), groups_n)[g]
    comp = fit_components(r, X, {"edge": U}, known=known)
    assert comp.s2 == pytest.approx(4.0, rel=0.1)
    if shared:
        assert comp.get("edge") == pytest.approx(shared, rel=0.6)
    else:
        assert comp.get("edge") < 0.1
    parts = sandwich(X, {"edge": U}, comp, known=known)
    # without the shared error: the covariance of weighted least squares with weights 1/s2 and 1
    if not shared:
        w = np.where(known, 1.0, 1.0 / comp.s2)
        np.testing.assert_allclose(sum(parts.values()), np.linalg.inv(X.T @ (X * w[:, None])), rtol=1e-8)


@pytest.mark.parametrize("x0, minimum", [(0.0, 0.3), (0.0, -0.2), (2.0, 7.3), (-5.0, -19.6), (6.0, 9.4)])
def test_the_line_search_from_a_start_finds_the_minimum_a_whole_range_search_finds(x0, minimum):
    """The noise fit's sweeps search each log variance from where it stands (a bracket grown
    downhill, then Brent's parabolas): the same minimum as a bounded search over the whole
    range, inside the range or at its bound, in fewer evaluations."""
    from scipy.optimize import minimize_scalar

    from rigcal.problem.mocap_noise import _XATOL, _line_min

    a, b = -20.0, 10.0
    calls = []

    def fun(v):
        calls.append(v)
        return float(np.log1p((v - minimum) ** 2) + 0.1 * (v - minimum) ** 2)

    x, fx = _line_min(fun, x0, fun(x0), a, b)
    ours = len(calls) - 1
    whole = minimize_scalar(fun, bounds=(a, b), method="bounded", options={"xatol": _XATOL})
    assert all(a <= v <= b for v in calls)
    assert x == pytest.approx(whole.x, abs=3 * _XATOL)
    assert x == pytest.approx(float(np.clip(minimum, a, b)), abs=3 * _XATOL)
    assert fx == fun(x)
    if abs(x0 - minimum) < 1.0:  # a sweep's usual start, next to its optimum
        assert ours < whole.nfev
    else:  # the bracket's growth costs a few evaluations more
        assert ours <= whole.nfev + 6


def test_the_line_search_stops_at_a_bound_the_value_rises_from_and_keeps_a_flat_start():
    """A variance component the residuals do not need sits at its lower bound: the search
    from there confirms it in two evaluations; on a flat function it finds nothing lower."""
    from rigcal.problem.mocap_noise import _line_min

    calls = []

    def rising(v):
        calls.append(v)
        return v

    x, fx = _line_min(rising, -30.0, -30.0, -30.0, 12.0)
    assert (x, fx) == (-30.0, -30.0) and len(calls) == 2
    x, fx = _line_min(lambda v: 1.0, 3.0, 1.0, -30.0, 12.0)
    assert fx == 1.0 and -30.0 <= x <= 12.0
