"""Curve fitting: approximation within a tolerance (A9.10 style) and plain least squares (A9.7).

References: Piegl and Tiller, *The NURBS Book*, 2nd ed.: section 9.4.1 and A9.10 (approximation to
within a tolerance by knot removal and degree elevation), A5.8 and eq. 5.28-5.30 (knot removal and
its error bound; the paper's eq. 5), A9.7 / eq. 9.63-9.67 (least squares with the end points
interpolated), eq. 9.5 (chord-length parameters), eq. 9.68-9.69 (least-squares knots).

The deviation reported is the maximum over the data of ``|C(u_k) - Q_k|``. For
:func:`fit_curve_lstsq` ``u_k`` are the data parameters (chord length unless given); for
:func:`fit_curve` they are the parameters after point projection (parameter correction, Newton
steps towards the closest point), so the value is an upper bound of (and in practice equal to)
the true closest distance from each point to the curve: every point is within ``E`` of the curve.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, solveh_banded

from ..errors import NurbscanError
from .basis import (
    approximation_knots,
    averaging_knots,
    basis_function_derivatives,
    basis_functions,
    chord_length_params,
    find_span,
)
from .curve import NurbsCurve, elevate_degree_h

__all__ = ["fit_curve", "fit_curve_lstsq", "fit_curves"]


# ----------------------------------------------------------------------------- helpers
def _check_points(points, degree: int, params):
    Q = np.asarray(points, dtype=float)
    if Q.ndim != 2 or Q.shape[1] < 1:
        raise NurbscanError(f"points: expected shape (m, d), got {Q.shape}")
    if not np.all(np.isfinite(Q)):
        raise NurbscanError("points: must be finite")
    if int(degree) < 1:
        raise NurbscanError(f"degree: must be >= 1, got {degree}")
    if Q.shape[0] < int(degree) + 1:
        raise NurbscanError(
            f"points: {Q.shape[0]} points cannot define a curve of degree {degree}"
        )
    if params is None:
        u = chord_length_params(Q)
    else:
        u = np.asarray(params, dtype=float)
        if u.shape != (Q.shape[0],) or not np.all(np.isfinite(u)):
            raise NurbscanError(f"params: expected {Q.shape[0]} finite values, got {u.shape}")
        if np.any(np.diff(u) < 0) or not u[-1] > u[0]:
            raise NurbscanError("params: must be non-decreasing with u[-1] > u[0]")
    return Q, u


def _eval_at(p, U, P, u, span=None, N=None):
    """Non-rational B-spline values at ``u``; returns (C, span, N)."""
    if span is None:
        span = find_span(P.shape[0] - 1, p, u, U)
        N = basis_functions(span, u, p, U)
    idx = span[:, None] - p + np.arange(p + 1)
    return np.einsum("kj,kjc->kc", N, P[idx]), span, N


def _difference_gram(n1: int, k: int) -> np.ndarray:
    """Upper-banded ``D^T D`` of the ``k``-th difference operator on ``n1`` values, (k + 1, n1).

    ``k`` is 1 or 2 (first or second differences), ``n1 > k``.
    """
    out = np.zeros((k + 1, n1))
    if k == 1:
        out[1] = 2.0
        out[1, [0, -1]] = 1.0
        out[0, 1:] = -1.0
        return out
    out[2] = 6.0
    out[2, [0, -1]] = 1.0
    if n1 > 2:
        out[2, [1, -2]] = 5.0
    out[1, 1:] = -4.0
    out[1, [1, -1]] = -2.0
    out[0, 2:] = 1.0
    if n1 == 3:
        out[2] = [1.0, 4.0, 1.0]
        out[1, 1:] = -2.0
    return out


def _lsq(p, U, u, Q, smooth=1e-9):
    """Least squares with the ends interpolated (A9.7, eq. 9.63-9.67), banded normal equations.

    With ``smooth > 0`` the normal matrix gets ``smooth * mean(diag) * D^T D`` (``D`` the
    ``min(p, 2)``-th difference of the control points): a negligible term that keeps the system
    regular when some basis function has no data in its support (the knots after degree
    elevation), filling such gaps with the smoothest control points.
    Returns the control points ``(n + 1, d)``, the spans and the basis values at ``u``.
    """
    n1 = U.size - p - 1
    d = Q.shape[1]
    span = find_span(n1 - 1, p, u, U)
    N = basis_functions(span, u, p, U)
    first = span - p
    # normal matrix N^T N in upper band form, ab[p - (j - i), j] = sum_k N_i(u_k) N_j(u_k),
    # accumulated with one bincount over (row offset, column)
    a_, b_ = np.triu_indices(p + 1)
    vals = N[:, a_] * N[:, b_]  # (m, pairs)
    flat = (p - (b_ - a_)) * n1 + first[:, None] + b_
    ab = np.bincount(flat.ravel(), vals.ravel(), minlength=(p + 1) * n1).reshape(p + 1, n1)
    idx = (first[:, None] + np.arange(p + 1)).ravel()
    rhs = np.empty((n1, d))
    for c in range(d):
        rhs[:, c] = np.bincount(idx, (N * Q[:, c : c + 1]).ravel(), minlength=n1)
    P = np.empty((n1, d))
    P[0] = Q[0]
    P[-1] = Q[-1]
    if n1 == 2:
        return P, span, N
    if smooth > 0:
        k = min(p, 2, n1 - 1)
        mu = smooth * max(float(ab[p].mean()), 1e-300)
        ab[p - k :] += mu * _difference_gram(n1, k)
    # move the fixed end points to the right-hand side: A[i, 0] = ab[p - i, i], i = 1..p
    k = np.arange(1, min(p, n1 - 1) + 1)
    rhs[k] -= ab[p - k, k][:, None] * Q[0]
    j = np.arange(max(n1 - 1 - p, 1), n1 - 1)
    rhs[j] -= ab[p - (n1 - 1 - j), n1 - 1][:, None] * Q[-1]
    try:
        if n1 - 2 <= 2:  # tiny systems: LAPACK's banded tridiagonal path needs >= 2 unknowns
            sub = ab[:, 1 : n1 - 1]
            k = n1 - 2
            A = np.zeros((k, k))
            for off in range(min(p, k - 1) + 1):
                j = np.arange(off, k)
                A[j - off, j] = sub[p - off, j]
                A[j, j - off] = sub[p - off, j]
            P[1:-1] = np.linalg.solve(A, rhs[1 : n1 - 1])
        else:
            P[1:-1] = solveh_banded(ab[:, 1 : n1 - 1], rhs[1 : n1 - 1], lower=False,
                                    check_finite=False)
    except (LinAlgError, np.linalg.LinAlgError):
        raise NurbscanError(
            "points: least-squares system is singular (too few points between knots)"
        ) from None
    return P, span, N


def _range_max(e: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``max(e[lo:hi])`` for many ranges (0 for empty ones), by a sparse table."""
    m = e.size
    table = [e]
    k = 1
    while 2 * k <= m:
        prev = table[-1]
        table.append(np.maximum(prev[:-k], prev[k:]))
        k *= 2
    length = hi - lo
    out = np.zeros(lo.shape)
    ok = length > 0
    if not np.any(ok):
        return out
    L = length[ok]
    lev = np.floor(np.log2(L)).astype(int)
    lo_ok = lo[ok]
    hi_ok = hi[ok]
    res = np.empty(L.size)
    for lv in np.unique(lev):
        sel = lev == lv
        t = table[lv]
        res[sel] = np.maximum(t[lo_ok[sel]], t[hi_ok[sel] - (1 << lv)])
    out[ok] = res
    return out


def _removal_bounds(p, U, P):
    """Removal bound ``B_r`` and new control points of one removal of every distinct interior knot.

    A5.8 with ``t = 0``, vectorised over knots: the control points are computed from the left and
    the right (eq. 5.28-5.29); ``B_r`` is the distance checked by A5.8 (for an even number of
    affected points the two estimates of the shared point are averaged, which halves the bound).
    For a non-rational curve the curve moves by at most ``B_r`` (eq. 5.30 with unit weights).

    Returns (r, s, Br, groups): last index and multiplicity of each knot, the bounds, and per
    multiplicity ``s`` the candidate indices and their new points ``(k, p - s, d)``.
    """
    n = P.shape[0] - 1
    iu = np.arange(p + 1, n + 1)
    is_last = U[iu] != U[iu + 1]
    is_first = U[iu] != U[iu - 1]
    r_all = iu[is_last]
    s_all = r_all - iu[is_first] + 1
    d = P.shape[1]
    nc = r_all.size
    Br = np.empty(nc)
    groups = {}
    for s in np.unique(s_all):
        sel = np.nonzero(s_all == s)[0]
        r = r_all[sel]
        uk = U[r]
        c = p - s + 1
        nit = c // 2
        first = r - p
        last = r - s
        Lp = P[first - 1]
        Rp = P[last + 1]
        Ls, Rs = [], []
        for a in range(nit):
            i = first + a
            al = ((uk - U[i]) / (U[i + p + 1] - U[i]))[:, None]
            Lp = (P[i] - (1.0 - al) * Lp) / al
            j = last - a
            aj = ((uk - U[j]) / (U[j + p + 1] - U[j]))[:, None]
            Rp = (P[j] - aj * Rp) / (1.0 - aj)
            Ls.append(Lp)
            Rs.append(Rp)
        if c % 2 == 0:
            Br[sel] = 0.5 * np.linalg.norm(Ls[-1] - Rs[-1], axis=1)
            mid = 0.5 * (Ls[-1] + Rs[-1])
            pts = Ls[:-1] + [mid] + Rs[-2::-1]
        else:
            i = first + nit
            al = ((uk - U[i]) / (U[i + p + 1] - U[i]))[:, None]
            blend = al * Rp + (1.0 - al) * Lp
            Br[sel] = np.linalg.norm(P[i] - blend, axis=1)
            pts = Ls + Rs[::-1]
        groups[int(s)] = (sel, np.stack(pts, axis=1) if pts else np.empty((sel.size, 0, d)))
    return r_all, s_all, Br, groups


def _removal_pass(p, U, P, u, e, E):
    """One pass of simultaneous knot removals within the accumulated bound (A5.8, A9.10).

    A knot is removable if ``B_r + max e_k <= E`` over the data whose parameters lie strictly
    inside the support of the changed basis functions, as in A9.10 (:func:`_removal_bounds`).
    Knots whose removals do not interact (supports meeting at most at an end) are removed
    together, small bounds first (a maximal independent set built in a few vectorised rounds);
    their bounds are added to the errors of the data they affect.

    Returns (U, P, e, n_removed).
    """
    n = P.shape[0] - 1
    if n < p + 1:
        return U, P, e, 0
    d = P.shape[1]
    r_all, s_all, Br, groups = _removal_bounds(p, U, P)
    nc = r_all.size
    # data affected: parameters strictly inside [U[r - p], U[r - s + p + 1]]
    zs = r_all - p
    ze = r_all - s_all + p + 1
    lo = np.searchsorted(u, U[zs], side="right")
    hi = np.searchsorted(u, U[ze], side="left")
    emax = _range_max(e, lo, hi)
    alive = Br + emax <= E
    if not np.any(alive):
        return U, P, e, 0
    # maximal independent set of non-interfering removals (supports meet at most at an end)
    W = 2 * p + 1
    chosen = np.zeros(nc, dtype=bool)
    order = np.empty(nc)
    order[np.argsort(Br, kind="stable")] = np.arange(nc)
    while np.any(alive):
        best = alive.copy()
        for o in range(1, W + 1):
            # neighbour k + o conflicts with k if zs[k + o] < ze[k]
            conf = zs[o:] < ze[:-o] if o < nc else np.zeros(0, dtype=bool)
            both = conf & alive[o:] & alive[:-o]
            # k loses to k + o when k + o is better, and vice versa
            lose_left = both & (order[o:] < order[:-o])
            lose_right = both & (order[:-o] < order[o:])
            best[:-o][lose_left] = False
            best[o:][lose_right] = False
        chosen |= best
        alive &= ~best
        for o in range(1, W + 1):
            if o >= nc:
                break
            conf = zs[o:] < ze[:-o]
            alive[o:] &= ~(conf & best[:-o])
            alive[:-o] &= ~(conf & best[o:])
    idx = np.nonzero(chosen)[0]
    # apply: drop old points first..last of each removal, insert its c - 1 new points
    keys = [np.arange(n + 1, dtype=float)]
    blocks = [P]
    drop = np.zeros(n + 1, dtype=bool)
    for s, (sel, pts) in groups.items():
        pick = np.nonzero(chosen[sel])[0]
        if pick.size == 0:
            continue
        r = r_all[sel[pick]]
        first = r - p
        c = p - s + 1
        cover = first[:, None] + np.arange(c)
        drop[cover.ravel()] = True
        if c > 1:
            keys.append((first[:, None] + np.arange(c - 1)).ravel().astype(float) + 0.5)
            blocks.append(pts[pick].reshape(-1, d))
    keys[0] = keys[0][~drop]
    blocks[0] = P[~drop]
    allk = np.concatenate(keys)
    P_new = np.concatenate(blocks)[np.argsort(allk, kind="stable")]
    U_new = np.delete(U, r_all[idx])
    de = np.zeros(e.size + 1)
    np.add.at(de, lo[idx], Br[idx])
    np.add.at(de, hi[idx], -Br[idx])
    e_new = e + np.cumsum(de[:-1])
    return U_new, P_new, e_new, idx.size


def _remove_knots(p, U, P, u, e, E, max_passes=200):
    """Repeat :func:`_removal_pass` until no knot can be removed."""
    total = 0
    for _ in range(max_passes):
        U, P, e, k = _removal_pass(p, U, P, u, e, E)
        total += k
        if k == 0:
            break
    return U, P, e, total


def _verified_removal(p, U, P, u, Q, E, err, max_fits=16):
    """Remove knots in batches ranked by their A5.8 bound, each batch verified by a refit.

    The bounds of A9.10 add up pessimistically (a least-squares refit after a removal moves the
    curve much less than ``B_r``), so at the target degree knots are also removed by trial: the
    distinct knots whose key ``B_r + max e_k`` (over the data in the removal's support) is a
    local minimum among their neighbours lose one occurrence each, the curve is refitted by
    least squares (A9.7) on the remaining knots, and the knots removed near data that now
    deviate by more than ``E`` are put back (in widening neighbourhoods) and the curve refitted
    again. A batch is kept only when every data point is within ``E``; a failed batch is retried
    with the best quarter of its knots, down to single knots (the three best-ranked are tried).
    """
    fits = 0
    frac = 1.0
    skip = 0
    changed = True
    while fits < max_fits and P.shape[0] > p + 1:
        if changed:
            r_all, s_all, Br, _ = _removal_bounds(p, U, P)
            nc = r_all.size
            if nc == 0:
                break
            lo = np.searchsorted(u, U[r_all - p], side="right")
            hi = np.searchsorted(u, U[r_all - s_all + p + 1], side="left")
            key = Br + _range_max(err, lo, hi)
            changed = False
        kp = np.concatenate([[np.inf], key, [np.inf]])
        sel = np.nonzero((key <= kp[:-2]) & (key < kp[2:]))[0]
        count = max(1, int(np.ceil(frac * sel.size)))
        if count == 1:
            # single removals: the best-ranked knot, then the next ones after failures
            if skip >= min(3, nc):
                break
            sel = np.argsort(key, kind="stable")[skip : skip + 1]
        elif count < sel.size:
            sel = np.sort(sel[np.argsort(key[sel], kind="stable")[:count]])
        cand = r_all[sel]
        vals = U[cand]
        active = np.ones(cand.size, dtype=bool)
        done = False
        for it in range(4):
            U2 = np.delete(U, cand[active])
            fits += 1
            try:
                P2, span, N = _lsq(p, U2, u, Q)
            except NurbscanError:
                break
            C, _, _ = _eval_at(p, U2, P2, u, span, N)
            e2 = np.linalg.norm(C - Q, axis=1)
            bad = e2 > E
            if not np.any(bad):
                done = True
                break
            # put back the removed knots near the offending data
            sp = span[bad]
            lo_v = U2[np.maximum(sp - it, 0)]
            hi_v = U2[np.minimum(sp + 1 + it, U2.size - 1)]
            a_ = np.searchsorted(vals, lo_v, side="left")
            b_ = np.searchsorted(vals, hi_v, side="right")
            mark = np.zeros(cand.size + 1)
            np.add.at(mark, a_, 1.0)
            np.add.at(mark, b_, -1.0)
            active &= ~(np.cumsum(mark[:-1]) > 0)
            if not np.any(active):
                break
        if done and np.any(active):
            U, P, err = U2, P2, e2
            changed = True
            frac = min(1.0, 2.0 * frac)
            skip = 0
        elif count == 1:
            skip += 1
        else:
            frac *= 0.25
    return U, P, u, err


def _project(p, U, P, u, Q, err, iters=1):
    """Parameter correction: Newton steps towards the closest curve points (section 9.4.1).

    ``u <- u - f / f'`` with ``f = (C(u) - Q) . C'(u)`` and ``f' = |C'|^2 + (C - Q) . C''``
    (eq. 6.3-6.4, point projection), clamped to the domain; the end points keep their parameters.
    A step is kept only where it lowers the point's deviation and the parameters stay ordered.
    Returns the parameters and the deviations ``|C(u_k) - Q_k|`` at them.
    """
    n = P.shape[0] - 1
    for _ in range(iters):
        span = find_span(n, p, u, U)
        D = basis_function_derivatives(span, u, p, 2, U)
        idx = span[:, None] - p + np.arange(p + 1)
        C, C1, C2 = np.einsum("kmj,mjc->kmc", D, P[idx])
        r = C - Q
        f = np.einsum("mc,mc->m", r, C1)
        df = np.einsum("mc,mc->m", C1, C1) + np.einsum("mc,mc->m", r, C2)
        step = np.where(df > 0, f / np.where(df > 0, df, 1.0), 0.0)
        un = np.clip(u - step, U[p], U[n + 1])
        un[0], un[-1] = u[0], u[-1]
        en = _errors(p, U, P, un, Q)
        better = en < err
        un = np.where(better, un, u)
        if np.any(np.diff(un) < 0):
            break
        u = un
        err = np.where(better, en, err)
    return u, err


def _fit(p, U, u, Q):
    """Least-squares control points (:func:`_lsq`) and the deviations at ``u``."""
    P, span, N = _lsq(p, U, u, Q)
    C, _, _ = _eval_at(p, U, P, u, span, N)
    return P, np.linalg.norm(C - Q, axis=1)


def _errors(p, U, P, u, Q):
    C, _, _ = _eval_at(p, U, P, u)
    return np.linalg.norm(C - Q, axis=1)


# ----------------------------------------------------------------------------- public
def fit_curve(points, degree: int = 3, tolerance: float = 0.01, params=None,
              max_refine: int = 20, return_params: bool = False):
    """Approximate points by a B-spline of the given degree within ``tolerance`` (A9.10 style).

    Steps (The NURBS Book section 9.4.1): the degree-1 curve through all points at their
    chord-length parameters (eq. 9.5); knot removal (A5.8, bound eq. 5.28-5.30, the paper's eq. 5)
    while the accumulated bound of every point stays under ``E``, many non-interacting knots per
    vectorised pass; then for each degree up to ``degree``: degree elevation and a least-squares
    refit with the end points interpolated (A9.7 / eq. 9.63) - first in the smoother space with
    the same knots (continuity raised), else in A9.10's space with every knot once more -
    parameter correction by point projection, errors reset to the true deviations, and knot
    removal again. At the final degree knots are then removed in verified batches (ranked by the
    A5.8 bound, each batch refitted and kept only if every point stays within ``E``), the
    parameters are corrected again, and the knots are respread by eq. 9.68-9.69 while one
    control point fewer still fits within ``E``. If the result exceeded ``E``, knots would be
    inserted in the offending spans and the curve refitted, up to ``max_refine`` times, and then
    the fit refused ("diverging fit").

    Parameters
    ----------
    points : array_like, shape (m, d)
        Data points ``Q_k`` (px for image curves, mm in 3-D), in order along the curve.
    degree : int
        Target degree ``p`` (3 by default).
    tolerance : float
        ``E``, in the units of the points.
    params : array_like, shape (m,), optional
        Non-decreasing parameters of the points; chord length on [0, 1] when omitted.
    max_refine : int
        Rounds of knot insertion allowed before giving up.
    return_params : bool
        Also return the final (projected) parameters of the points, shape (m,).

    Returns
    -------
    curve : NurbsCurve
        Non-rational, of the given degree, clamped, domain ``[u_0, u_{m-1}]``, the end points
        interpolated.
    max_deviation : float
        ``max_k |C(u_k) - Q_k|`` at the final parameters ``u_k`` (projected towards the closest
        curve points, section 9.4.1), an upper bound of the closest distance; ``<= tolerance``.
    params : ndarray, shape (m,)
        Only with ``return_params``: the ``u_k``.

    Raises
    ------
    NurbscanError
        Bad input, or "diverging fit" when ``E`` cannot be met.
    """
    Q, u = _check_points(points, degree, params)
    E = float(tolerance)
    if not E > 0:
        raise NurbscanError(f"tolerance: must be > 0, got {tolerance}")
    p_target = int(degree)
    # degree 1 through all points; coincident parameters keep the first point as the vertex
    if not np.ptp(Q, axis=0).max() > 0:
        raise NurbscanError("points: all points coincide")
    keep = np.concatenate([[True], np.diff(u) > 0])
    keep[-1] = True
    if np.count_nonzero(keep) < 2 or not u[-1] > u[0]:
        raise NurbscanError("points: all points coincide")
    uk = u[keep]
    if uk.size != np.unique(uk).size:  # last point shares the parameter of the previous one
        keep[np.nonzero(keep)[0][-2]] = False
        uk = u[keep]
    p = 1
    U = np.concatenate([[uk[0]], uk, [uk[-1]]])
    P = Q[keep].copy()
    e = _errors(p, U, P, u, Q)
    U, P, e, _ = _remove_knots(p, U, P, u, e, E)
    while p < p_target:
        # first try the smoother space: same interior knots, one degree up (one more control
        # point, continuity raised by one); if it misses E use the elevated space of A9.10
        # (every distinct knot once more), which contains the current curve exactly.
        U_s = np.concatenate([[U[0]], U, [U[-1]]])
        P_s, e_s = _fit(p + 1, U_s, u, Q)
        if e_s.max() <= E:
            U, P, e = U_s, P_s, e_s
            p += 1
            u, e = _project(p, U, P, u, Q, e)
        else:
            U, P = elevate_degree_h(p, U, P, 1)
            p += 1
            P_ls, e_ls = _fit(p, U, u, Q)
            if e_ls.max() <= E:
                P, e = P_ls, e_ls
                u, e = _project(p, U, P, u, Q, e)
        U, P, e, _ = _remove_knots(p, U, P, u, e, E)
    err = _errors(p, U, P, u, Q)
    if err.max() <= E:
        U, P, u, err = _verified_removal(p, U, P, u, Q, E, err)
        u, err = _project(p, U, P, u, Q, err, iters=2)
        # knot relocation: the spread knots of eq. 9.68-9.69 with one control point fewer
        while P.shape[0] > p + 1:
            n_try = min(P.shape[0] - 1, u.size)
            try:
                if n_try == u.size:  # more control points than data: interpolate (eq. 9.8)
                    U2 = averaging_knots(u, p)
                else:
                    U2 = approximation_knots(u, p, n_try)
                P2, span, N = _lsq(p, U2, u, Q)
            except NurbscanError:
                break
            e2 = np.linalg.norm(_eval_at(p, U2, P2, u, span, N)[0] - Q, axis=1)
            if not e2.max() <= E:
                break
            U, P = U2, P2
            u, err = _project(p, U, P, u, Q, e2, iters=2)
    err = _errors(p, U, P, u, Q)
    for _ in range(max_refine):
        if err.max() <= E:
            break
        U, P = _refine_where(p, U, P, u, err > E)
        P, err = _fit(p, U, u, Q)
    if not err.max() <= E:
        raise NurbscanError(
            f"points: diverging fit, max deviation {err.max():.3g} > tolerance {E:.3g}"
        )
    curve = NurbsCurve(p, U, P)
    if return_params:
        return curve, float(err.max()), u
    return curve, float(err.max())


def _refine_where(p, U, P, u, bad):
    """Insert the midpoint of every knot span holding a point with ``bad`` set (A5.1)."""
    span = find_span(P.shape[0] - 1, p, u[bad], U)
    spans = np.unique(span)
    mids = 0.5 * (U[spans] + U[spans + 1])
    curve = NurbsCurve(p, U, P)
    curve = curve.insert_knots(mids)
    return np.array(curve.knots), np.array(curve.control_points)


def _fit_one(args):
    points, degree, tolerance = args
    return fit_curve(points, degree, tolerance)


def fit_curves(curves, degree: int = 3, tolerance: float = 0.01, workers: int = 1):
    """:func:`fit_curve` on many point sequences, optionally in ``workers`` processes.

    Parameters
    ----------
    curves : sequence of array_like, each (m_i, d)
    degree, tolerance : as in :func:`fit_curve`
    workers : int
        Number of processes (1: in this process).

    Returns
    -------
    list of (NurbsCurve, float)
        In the order of ``curves``; a curve that cannot be fitted raises its NurbscanError.
    """
    jobs = [(np.asarray(c, dtype=float), int(degree), float(tolerance)) for c in curves]
    if int(workers) <= 1 or len(jobs) < 2:
        return [_fit_one(j) for j in jobs]
    from concurrent.futures import ProcessPoolExecutor

    chunk = max(1, len(jobs) // (4 * int(workers)))
    with ProcessPoolExecutor(max_workers=int(workers)) as ex:
        return list(ex.map(_fit_one, jobs, chunksize=chunk))


def fit_curve_lstsq(points, n_ctrl: int, degree: int = 3, params=None) -> tuple[NurbsCurve, float]:
    """Least-squares B-spline with ``n_ctrl`` control points, the ends interpolated (A9.7).

    Knots from eq. 9.68-9.69 on the chord-length parameters (eq. 9.5) unless ``params`` given.

    Returns
    -------
    curve : NurbsCurve
    max_deviation : float
        ``max_k |C(u_k) - Q_k|`` at the data parameters (units of the points).
    """
    Q, u = _check_points(points, degree, params)
    p = int(degree)
    n_ctrl = int(n_ctrl)
    U = approximation_knots(u, p, n_ctrl)
    P, _, _ = _lsq(p, U, u, Q, smooth=0.0)
    err = _errors(p, U, P, u, Q)
    return NurbsCurve(p, U, P), float(err.max())
