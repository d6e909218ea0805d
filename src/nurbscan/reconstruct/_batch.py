"""Batched least-squares fitting of many short uniform cubic B-splines at once.

Thousands of short chains (edge lines split at band crossings) are fitted per view; a Python
loop over them with one small solve each costs more than the arithmetic. Here every chain's
parameters are normalised to [0, 1]; chains with the same number of knot spans share one clamped
uniform knot vector there, so one :func:`~nurbscan.nurbs.basis.basis_matrix` call serves the
whole group; the banded normal equations (Piegl and Tiller eq. 9.66) of all chains are
assembled from the non-zero basis values in one compiled loop (numba: the sums of
``np.bincount`` in the same order, 4 x faster) and solved together with a batched
``np.linalg.solve``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .._jit import njit
from ..nurbs.basis import basis_functions, find_span


@lru_cache(maxsize=1024)
def uniform_knots01(n_spans: int, degree: int = 3) -> np.ndarray:
    """Clamped uniform knots on [0, 1] with ``n_spans`` spans (read-only; one array per
    ``(n_spans, degree)``: thousands of chains per view share a few dozen knot vectors)."""
    inner = np.linspace(0.0, 1.0, n_spans + 1)
    U = np.concatenate([np.zeros(degree), inner, np.ones(degree)])
    U.flags.writeable = False
    return U


def _local_basis(t: np.ndarray, n: int, degree: int):
    """Spans (N,) and non-zero basis values (N, degree + 1) on the uniform knots of n spans."""
    U = uniform_knots01(n, degree)
    span = find_span(n + degree - 1, degree, t, U)
    return span - degree, basis_functions(span, t, degree, U)


def _solve_group(first, Nb, Y, w, local, C, m, smooth):
    """Per-chain weighted normal equations, assembled sparsely, solved in one batch.

    ``first`` (N,) is the index of each point's first non-zero basis function, ``Nb`` (N, p+1)
    the values, ``local`` (N,) the chain of each point within the group (0 .. C - 1).
    """
    M, rhs = _normal_equations(first, Nb, np.asarray(Y, np.float64), np.asarray(w, np.float64),
                               local, C, m)
    cnt = np.bincount(local, w, C)
    if m > 2:
        D = np.diff(np.eye(m), 2, axis=0)
        M = M + (smooth * np.maximum(cnt, 1.0) / m)[:, None, None] * (D.T @ D)[None]
    M = M + 1e-12 * np.eye(m)[None]
    return np.linalg.solve(M, rhs)


@njit(cache=True, nogil=True)
def _normal_equations(first, Nb, Y, w, local, C, m):
    """The chains' normal matrices ``sum_n w_n N_n N_n^T`` (C, m, m) and right-hand sides
    ``sum_n w_n N_n y_n`` (C, m, d), each entry accumulated over the points in their order
    (as ``np.bincount`` does, bit for bit), from the non-zero basis values only."""
    n, p1 = Nb.shape
    d = Y.shape[1]
    M = np.zeros((C, m, m))
    rhs = np.zeros((C, m, d))
    for i in range(n):
        c, f = local[i], first[i]
        for a in range(p1):
            nw = Nb[i, a] * w[i]
            for b in range(p1):
                M[c, f + a, f + b] += nw * Nb[i, b]
            for k in range(d):
                rhs[c, f + a, k] += nw * Y[i, k]
    return M, rhs


@njit(cache=True, nogil=True)
def _lower_medians(res, starts):
    """Per chain (the contiguous runs of ``res`` from ``starts``), the lower median: element
    ``(n - 1) // 2`` of the run sorted, NaN last (as ``np.lexsort((res, chain))`` orders)."""
    out = np.empty(len(starts))
    for k in range(len(starts)):
        a = starts[k]
        b = starts[k + 1] if k + 1 < len(starts) else len(res)
        out[k] = np.sort(res[a:b])[(b - a - 1) // 2]
    return out


def _apply(first, Nb, P, local):
    """Fitted points: sum of the non-zero basis values times their control points."""
    r = first[:, None] + np.arange(Nb.shape[1])[None]
    return np.einsum("nk,nkd->nd", Nb, P[local[:, None], r])


def fit_chains(t: np.ndarray, Y: np.ndarray, chain: np.ndarray, n_spans: np.ndarray,
               degree: int = 3, smooth: float = 1e-6, robust: float | None = None,
               return_fitted: bool = False):
    """Least-squares cubic B-splines of many chains, optionally with one outlier pass.

    Parameters
    ----------
    t : ndarray (N,)
        Parameters normalised to [0, 1] within each chain.
    Y : ndarray (N, d)
        Data points.
    chain : ndarray int (N,)
        Chain id 0 .. C - 1 of each point; points of a chain must be contiguous.
    n_spans : ndarray int (C,)
        Knot spans of each chain.
    smooth : float
        Weight of a second-difference penalty on the control points (relative to the data).
    robust : float or None
        If given, points farther than ``max(3 * 1.4826 * median residual, robust)`` from the
        first fit are dropped and the chain is refitted.

    Returns
    -------
    ctrl : list of ndarray (n_spans[c] + degree, d)
    inlier : ndarray bool (N,)
    rms : ndarray (C,)
        RMS residual of the inliers.
    fitted : ndarray (N, d)
        With ``return_fitted``: the fitted chains at ``t``, as :func:`evaluate_chains` gives
        them (the same numbers; kept from the fit rather than computed again).
    """
    C = len(n_spans)
    ctrl: list = [None] * C
    inlier = np.ones(len(t), bool)
    rms = np.zeros(C)
    fitted = np.empty(Y.shape) if return_fitted else None
    # the points of the chains of each span count, in their order (one stable sort)
    key = n_spans[chain]
    by_spans = np.argsort(key, kind="stable")
    spans, at = np.unique(key[by_spans], return_index=True)
    bounds = np.r_[at, len(key)]
    for g, n in enumerate(spans):
        idx = by_spans[bounds[g]:bounds[g + 1]]
        cid = chain[idx]
        m = int(n) + degree
        first, Nb = _local_basis(t[idx], int(n), degree)
        Yg = Y[idx]
        starts = np.r_[0, np.nonzero(np.diff(cid))[0] + 1]
        Cg = len(starts)
        local = np.repeat(np.arange(Cg), np.diff(np.r_[starts, len(idx)]))
        w = np.ones(len(idx))
        P = _solve_group(first, Nb, Yg, w, local, Cg, m, smooth)
        fit = _apply(first, Nb, P, local)
        res = np.linalg.norm(fit - Yg, axis=1)
        if robust is not None:
            med = _lower_medians(res, starts)
            lim = np.maximum(3.0 * 1.4826 * med, robust)[local]
            w = (res <= lim).astype(float)
            ok = (np.bincount(local, w, Cg) >= min(4, m))[local]
            w = np.where(ok, w, 1.0)
            P = _solve_group(first, Nb, Yg, w, local, Cg, m, smooth)
            fit = _apply(first, Nb, P, local)
            res = np.linalg.norm(fit - Yg, axis=1)
            inlier[idx] = w > 0
        if fitted is not None:
            fitted[idx] = fit
        r2 = np.bincount(local, res**2 * w, Cg) / np.maximum(np.bincount(local, w, Cg), 1)
        for k, c in enumerate(cid[starts]):
            ctrl[c] = P[k]
            rms[c] = np.sqrt(r2[k])
    return (ctrl, inlier, rms, fitted) if return_fitted else (ctrl, inlier, rms)


def evaluate_chains(t: np.ndarray, chain: np.ndarray, n_spans: np.ndarray, ctrl: list,
                    degree: int = 3) -> np.ndarray:
    """Points of the fitted chains at normalised parameters ``t`` (N,), shape (N, d)."""
    d = next((c.shape[1] for c in ctrl if c is not None), 0)
    out = np.empty((len(t), d))
    for n in np.unique(n_spans[chain]):
        sel = np.nonzero(n_spans[chain] == n)[0]
        first, Nb = _local_basis(t[sel], int(n), degree)
        ids = np.unique(chain[sel])
        P = np.stack([ctrl[c] for c in ids])
        out[sel] = _apply(first, Nb, P, np.searchsorted(ids, chain[sel]))
    return out


def pair_quadratic_rms(w: np.ndarray, P: np.ndarray, a_lo: np.ndarray, a_hi: np.ndarray,
                       b_lo: np.ndarray, b_hi: np.ndarray, k: int = 10) -> np.ndarray:
    """RMS residual (mm) of one quadratic in ``w`` through the ends of chain pairs, batched.

    Pair ``p`` uses the last ``k`` samples of ``[a_lo, a_hi)`` and the first ``k`` of
    ``[b_lo, b_hi)`` (index ranges into ``w`` and ``P``). Small when both chains lie on one
    smooth curve; large across a depth step or for a mislabelled chain.
    """
    n = len(a_lo)
    if n == 0:
        return np.zeros(0)
    j = np.arange(k)
    ia = a_hi[:, None] - k + j[None]
    ma = ia >= a_lo[:, None]
    ib = b_lo[:, None] + j[None]
    mb = ib < b_hi[:, None]
    idx = np.concatenate([np.where(ma, ia, 0), np.where(mb, ib, 0)], axis=1)
    msk = np.concatenate([ma, mb], axis=1).astype(float)
    ww = w[idx]
    cnt = msk.sum(1)
    mean = (ww * msk).sum(1) / cnt
    span = np.maximum(np.where(msk > 0, ww, -np.inf).max(1) - np.where(msk > 0, ww, np.inf).min(1),
                      1e-9)
    x = (ww - mean[:, None]) / span[:, None]
    A = np.stack([np.ones_like(x), x, x * x], axis=2) * msk[..., None]
    Y = P[idx] * msk[..., None]
    M = np.einsum("pni,pnj->pij", A, A) + 1e-12 * np.eye(3)[None]
    c = np.linalg.solve(M, np.einsum("pni,pnd->pid", A, Y))
    r = np.einsum("pni,pid->pnd", A, c) - Y
    rms = np.sqrt((r**2).sum((1, 2)) / cnt)
    return np.where(cnt >= 4, rms, np.inf)
