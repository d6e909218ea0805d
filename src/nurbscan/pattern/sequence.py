"""Pseudo-random multi-valued sequences: m-sequences over GF(q) and their de Bruijn extension.

method.md section 1. For a prime ``q`` and a window length ``n``, a monic polynomial of degree
``n`` over GF(q)

    p(x) = x^n + c[n-1] x^(n-1) + ... + c[1] x + c[0]

defines the linear recurrence (a linear feedback shift register over GF(q))

    a[k+n] = -(c[n-1] a[k+n-1] + ... + c[1] a[k+1] + c[0] a[k])  (mod q).

Its output has period q^n - 1, the largest possible, exactly when p is primitive (Lidl and
Niederreiter, *Finite Fields*, Thm. 8.33); it is then an *m-sequence*: every window of n
consecutive symbols except 0...0 appears exactly once per period. Inserting one extra 0 next to
a run of n - 1 zeros gives a de Bruijn sequence of length q^n, in which every window of n
symbols, 0...0 included, appears exactly once (cyclically).

Polynomial notation
-------------------
A polynomial is written by its coefficients from the highest degree down, leading 1 included:

* a string of base-q digits, ``"1403"`` = x^3 + 4x^2 + 0x + 3 (usable while every
  coefficient is below 10);
* a comma list ``"1,4,0,3"`` (needed for q > 10, e.g. ``"1,10,0,3"`` over GF(11));
* a sequence of ints ``[1, 4, 0, 3]``.

``"1403"`` is primitive over GF(5) (recurrence a[k+3] = a[k+2] + 2 a[k] mod 5) and is the
default for q = 5, n = 3; for other (q, n) the default is the first primitive polynomial found by
:func:`find_primitive`.

Conventions of this module
--------------------------
* The m-sequence starts from the state (a[0], ..., a[n-1]) = (0, ..., 0, 1); the de Bruijn
  sequence is ``[0] + m_sequence``, so it starts with the window 0...0 followed by a 1.
* A window (a[i], ..., a[i+n-1]) is encoded as the base-q integer
  ``key = a[i] q^(n-1) + ... + a[i+n-1]`` (first symbol most significant); window tables are
  dense int arrays of size q^n holding the start index of each window, -1 for absent.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..errors import NurbscanError

#: Largest sequence length q^n handled (the recurrence is stepped in Python, once per pattern).
MAX_LENGTH = 1 << 20

#: The default polynomial for (q, n) = (5, 3): x^3 + 4x^2 + 3, a[k+3] = a[k+2] + 2a[k] (mod 5).
DEFAULT_POLYS = {(5, 3): "1403"}

PolyLike = str | Sequence[int]


def is_prime(q: int) -> bool:
    """Return whether the integer ``q`` is prime (trial division; q is small)."""
    if q < 2:
        return False
    d = 2
    while d * d <= q:
        if q % d == 0:
            return False
        d += 1
    return True


def check_field(q: int, n: int) -> None:
    """Raise :class:`NurbscanError` unless q is prime, n >= 1 and q^n <= :data:`MAX_LENGTH`."""
    if isinstance(q, bool) or not isinstance(q, int | np.integer) or not is_prime(int(q)):
        raise NurbscanError(f"base q={q}: must be a prime (GF(q) is a field only for prime q)")
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise NurbscanError(f"window n={n}: must be an integer >= 1")
    if int(q) ** int(n) > MAX_LENGTH:
        raise NurbscanError(
            f"base q={q}, window n={n}: sequence length q^n = {int(q) ** int(n)} exceeds "
            f"{MAX_LENGTH}"
        )


def parse_poly(poly: PolyLike, q: int, n: int) -> tuple[int, ...]:
    """Parse a polynomial (see the module notes) into its n + 1 coefficients, highest first.

    Parameters
    ----------
    poly : str or sequence of int
        ``"1403"``, ``"1,4,0,3"`` or ``[1, 4, 0, 3]``.
    q, n : int
        The field size (prime) and the required degree.

    Returns
    -------
    coeffs : tuple of int, length n + 1
        ``(1, c[n-1], ..., c[0])``.

    Raises
    ------
    NurbscanError
        If the text is not digits / a comma list, a coefficient is not in 0..q-1, the degree is
        not n, or the polynomial is not monic.
    """
    check_field(q, n)
    label = poly if isinstance(poly, str) else ",".join(str(c) for c in poly)
    try:
        if isinstance(poly, str):
            text = poly.strip().replace(" ", "")
            if "," in text:
                coeffs = [int(t) for t in text.split(",")]
            elif text.isdigit():
                coeffs = [int(t) for t in text]
            else:
                raise ValueError
        else:
            coeffs = [int(c) for c in poly]
            if any(c != float(v) for c, v in zip(coeffs, poly, strict=True)):
                raise ValueError
    except (ValueError, TypeError):
        raise NurbscanError(
            f"polynomial {label!r}: not base-{q} digits or a comma list of integers "
            "(e.g. '1403' or '1,4,0,3', highest degree first)"
        ) from None
    if any(c < 0 or c >= q for c in coeffs):
        raise NurbscanError(
            f"polynomial {label!r}: coefficients must lie in 0..{q - 1} for GF({q})"
        )
    if len(coeffs) != n + 1:
        raise NurbscanError(
            f"polynomial {label!r}: has {len(coeffs)} coefficients, a degree-{n} polynomial "
            f"needs {n + 1} (highest degree first, leading 1 included)"
        )
    if coeffs[0] != 1:
        raise NurbscanError(f"polynomial {label!r}: must be monic (leading coefficient 1)")
    return tuple(coeffs)


def format_poly(coeffs: Sequence[int], q: int) -> str:
    """Canonical notation of coefficients (highest first): digits if q <= 10, else a comma list."""
    if q <= 10:
        return "".join(str(int(c)) for c in coeffs)
    return ",".join(str(int(c)) for c in coeffs)


def _taps(coeffs: Sequence[int], q: int) -> list[int]:
    """Feedback taps t[i] = -c[i] mod q, i = 0..n-1, so that a[k+n] = sum_i t[i] a[k+i]."""
    return [(-c) % q for c in reversed(coeffs[1:])]


def _run_lfsr(coeffs: Sequence[int], q: int, n: int, limit: int) -> tuple[list[int], int]:
    """Step the recurrence from the state (0, ..., 0, 1) until the state recurs or ``limit``.

    Returns the symbols a[0 .. period + n - 2] produced and the period (0 if the start state
    did not recur within ``limit`` steps, which happens when c[0] = 0).
    """
    taps = _taps(coeffs, q)
    qn1 = q ** (n - 1)
    a = [0] * (n - 1) + [1]
    start = key = 1  # base-q key of the state (first symbol most significant)
    for k in range(limit):
        new = sum(t * x for t, x in zip(taps, a[k:k + n], strict=True)) % q
        a.append(new)
        key = (key - a[k] * qn1) * q + new
        if key == start:
            return a, k + 1
    return a, 0


def recurrence_period(poly: PolyLike, q: int, n: int) -> int:
    """Period of the recurrence of ``poly`` started from the state (0, ..., 0, 1).

    Returns 0 if c[0] = 0 (the state map is singular and the start state never recurs).
    The polynomial is primitive exactly when the period is q^n - 1 (the orbit of one non-zero
    state then holds all q^n - 1 non-zero states, so the companion matrix has order q^n - 1).
    """
    coeffs = parse_poly(poly, q, n)
    if coeffs[-1] == 0:
        return 0
    return _run_lfsr(coeffs, q, n, q**n)[1]


def is_primitive(poly: PolyLike, q: int, n: int) -> bool:
    """Return whether ``poly`` is primitive over GF(q): its recurrence has period q^n - 1."""
    return recurrence_period(poly, q, n) == q**n - 1


def check_primitive(poly: PolyLike, q: int, n: int) -> tuple[int, ...]:
    """Parsed coefficients of ``poly``; :class:`NurbscanError` naming it if not primitive."""
    coeffs = parse_poly(poly, q, n)
    period = recurrence_period(coeffs, q, n)
    if period != q**n - 1:
        why = "constant term 0" if coeffs[-1] == 0 else f"recurrence period {period}"
        raise NurbscanError(
            f"polynomial {format_poly(coeffs, q)!r}: not primitive over GF({q}) ({why}, "
            f"a primitive degree-{n} polynomial gives period {q**n - 1})"
        )
    return coeffs


def find_primitive(q: int, n: int) -> str:
    """The first primitive monic degree-n polynomial over GF(q), by exhaustive search.

    Candidates are taken in increasing order of the base-q number c[n-1] ... c[0]; those with
    c[0] = 0 or (for n >= 2) a root in GF(q) are skipped, the rest are tested by their
    recurrence period. Returns the canonical notation (:func:`format_poly`).
    """
    check_field(q, n)
    xs = np.arange(q)
    for value in range(q**n):
        low = [(value // q**i) % q for i in range(n)]  # c[0], c[1], ..., c[n-1]
        if low[0] == 0:
            continue
        coeffs = (1, *reversed(low))
        if n >= 2 and np.any(np.polyval(np.array(coeffs), xs) % q == 0):
            continue
        if _run_lfsr(coeffs, q, n, q**n)[1] == q**n - 1:
            return format_poly(coeffs, q)
    raise NurbscanError(f"no primitive polynomial of degree {n} over GF({q})")  # pragma: no cover


def default_poly(q: int, n: int) -> str:
    """The default polynomial: ``"1403"`` for (5, 3), else :func:`find_primitive`."""
    return DEFAULT_POLYS.get((int(q), int(n))) or find_primitive(q, n)


def m_sequence(q: int, n: int, poly: PolyLike | None = None) -> np.ndarray:
    """One period of the m-sequence of a primitive polynomial.

    Parameters
    ----------
    q, n : int
        Prime field size and window length.
    poly : str or sequence of int, optional
        Primitive polynomial (module notation); default :func:`default_poly`.

    Returns
    -------
    seq : ndarray of int64, shape (q^n - 1,)
        a[0 .. q^n - 2], started from the state (0, ..., 0, 1); every window of n symbols
        except 0...0 appears exactly once, cyclically.

    Raises
    ------
    NurbscanError
        If ``poly`` is malformed or not primitive, or q is not prime.
    """
    coeffs = check_primitive(default_poly(q, n) if poly is None else poly, q, n)
    a, _ = _run_lfsr(coeffs, q, n, q**n - 1)
    return np.asarray(a[: q**n - 1], dtype=np.int64)


def de_bruijn(q: int, n: int, poly: PolyLike | None = None) -> np.ndarray:
    """The de Bruijn sequence of length q^n: one extra 0 before the m-sequence's leading zeros.

    The m-sequence starts with its run of n - 1 zeros (state 0...01); prepending a 0 makes the
    window 0...0 appear and removes none (method.md section 1).

    Returns
    -------
    seq : ndarray of int64, shape (q^n,)
        Every window of n symbols appears exactly once, cyclically.
    """
    return np.concatenate([[0], m_sequence(q, n, poly)]).astype(np.int64)


def window_keys(codes: np.ndarray, q: int) -> np.ndarray:
    """Encode windows of symbols as base-q integers (first symbol most significant).

    Parameters
    ----------
    codes : array_like of int, shape (..., n)
        Symbols in 0..q-1; any other value (e.g. -1 for an unread colour) marks the window
        invalid.

    Returns
    -------
    keys : ndarray of int64, shape (...)
        The key in 0..q^n - 1, or -1 for an invalid window.
    """
    codes = np.asarray(codes)
    if codes.ndim == 0:
        raise NurbscanError("window codes: need an array of shape (..., n), got a scalar")
    n = codes.shape[-1]
    if np.issubdtype(codes.dtype, np.integer):
        c = codes.astype(np.int64)
        valid = np.all((c >= 0) & (c < q), axis=-1)
    else:
        f = codes.astype(np.float64)
        c = np.where(np.isfinite(f), f, -1).astype(np.int64)
        valid = np.all((c >= 0) & (c < q) & (c == f), axis=-1)
    weights = q ** np.arange(n - 1, -1, -1, dtype=np.int64)
    keys = np.where(valid, (np.clip(c, 0, q - 1) * weights).sum(axis=-1), -1)
    return keys.astype(np.int64)


def window_table(seq: np.ndarray, q: int, n: int, cyclic: bool = False) -> np.ndarray:
    """Dense look-up table from window key to the start index of that window in ``seq``.

    Parameters
    ----------
    seq : array_like of int, shape (L,)
        Symbols in 0..q-1.
    cyclic : bool
        If true also the L windows wrapping around the end; otherwise the L - n + 1 windows
        that fit.

    Returns
    -------
    table : ndarray of int64, shape (q^n,)
        ``table[key]`` = start index of the window, -1 if absent.

    Raises
    ------
    NurbscanError
        If a window occurs twice (the sequence cannot be decoded by windows of length n).
    """
    seq = np.asarray(seq, dtype=np.int64)
    ext = np.concatenate([seq, seq[: n - 1]]) if cyclic else seq
    table = np.full(q**n, -1, dtype=np.int64)
    if ext.size < n:
        return table
    keys = window_keys(sliding_window_view(ext, n), q)
    if np.any(keys < 0):
        raise NurbscanError(f"sequence: symbols outside 0..{q - 1}")
    if np.unique(keys).size != keys.size:
        raise NurbscanError(f"sequence: a window of length {n} occurs more than once")
    table[keys] = np.arange(keys.size)
    return table


def window_lookup(codes: np.ndarray, table: np.ndarray, q: int) -> np.ndarray:
    """Vectorised O(1) look-up of windows ``codes`` (..., n) in a :func:`window_table`.

    Returns the start index per window, shape (...), -1 for absent or invalid windows.
    """
    codes = np.asarray(codes)
    if codes.ndim == 0 or q ** codes.shape[-1] != len(table):
        raise NurbscanError(
            f"window codes: last axis must be the window length n with q^n = {len(table)}, "
            f"got shape {codes.shape}"
        )
    keys = window_keys(codes, q)
    return np.where(keys >= 0, table[np.maximum(keys, 0)], -1)
