"""Numba kernel of the antenna CSV rows (:func:`dpos_ros.products.write.write_csv_rows`).

``np.savetxt`` formats every number through Python's ``%`` (~0.7 us each: 0.9 s for one
paper_wing antenna, 60 000 rows x 20 columns; a 4-hour flight's twelve antennas would take 9
minutes).  Here the digits are written into a byte buffer directly, from integers: ~20 ns a number.
Column kinds: ``FIXED`` (``%.<d>f``), ``EXP`` (``%.<d>e``), ``INT`` (``%d``); the stamp column is
written exactly from the integer nanoseconds (``<s>.<9 digits>``).  Rounding is to nearest of the
value scaled by ``10^d`` (printf rounds the exact binary value: the two can differ in the last digit
only for a value within a few ulps of a tie); NaN and infinities print as ``nan``, ``inf``, ``-inf``.

``EXP``'s decimal exponent is ``floor(log10(a))`` corrected by one step so that the mantissa
``a / 10.0**e`` is in ``[1, 10)``: the floor is found without a logarithm per number, from the
smallest value of each floor (:func:`log10_floor_starts`, found once by bisection with the same
``log10``) starting at the column's previous exponent, and ``10.0**e`` is read from a table of the
same expression (:func:`pow10_table`): the digits are those of ``log10`` and ``**`` per number.
"""

from __future__ import annotations

import numpy as np
from numba import njit

FIXED, EXP, INT = 0, 1, 2
#: the decimal exponents of the tables: index ``e - E_MIN`` (every positive double's ``floor(log10)``
#: +- 1 is in range)
E_MIN, E_MAX = -330, 330
#: the digit pairs "00".."99" (200,) uint8
PAIRS = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()


@njit(cache=True)
def pow10_table() -> np.ndarray:  # pragma: no cover - numba
    """``10.0**e`` (E_MAX - E_MIN + 1,) float64 for ``e`` in ``E_MIN..E_MAX``, by numba's own ``**``."""
    out = np.empty(E_MAX - E_MIN + 1)
    for i in range(out.size):
        e = i + E_MIN
        out[i] = 10.0**e
    return out


@njit(cache=True)
def _log10_floor(a: float) -> int:  # pragma: no cover - numba
    return int(np.floor(np.log10(a)))


@njit(cache=True)
def log10_floor_starts() -> np.ndarray:  # pragma: no cover - numba
    """Per ``e`` in ``E_MIN..E_MAX`` (E_MAX - E_MIN + 1,) float64 the smallest positive double ``a``
    with ``floor(log10(a)) >= e`` (``inf`` when none; the smallest double when all), by bisection
    over the doubles' bit patterns (ordered as the values); ``log10`` taken as non-decreasing."""
    out = np.empty(E_MAX - E_MIN + 1)
    bits = np.empty(1, np.int64)
    val = bits.view(np.float64)
    top = np.int64(0x7FEFFFFFFFFFFFFF)  # the largest finite double
    for i in range(out.size):
        e = i + E_MIN
        bits[0] = top
        if _log10_floor(val[0]) < e:
            out[i] = np.inf
            continue
        lo, hi = np.int64(0), top  # invariant: floor(log10(bits lo)) < e <= floor(log10(bits hi)) (lo = 0: a = 0)
        bits[0] = np.int64(1)
        if _log10_floor(val[0]) >= e:
            out[i] = val[0]
            continue
        lo = np.int64(1)
        while hi - lo > 1:
            mid = lo + (hi - lo) // 2
            bits[0] = mid
            if _log10_floor(val[0]) >= e:
                hi = mid
            else:
                lo = mid
        bits[0] = hi
        out[i] = val[0]
    return out


@njit(cache=True, inline="always")
def _ndigits(v: int) -> int:  # pragma: no cover - numba
    """The number of decimal digits of ``v`` >= 0 (1 for 0)."""
    n = 1
    while v >= 10:
        if v >= 10_000:
            v //= 10_000
            n += 4
        else:
            v //= 10
            n += 1
    return n


@njit(cache=True, inline="always")
def _uint(buf, pos, v):  # pragma: no cover - numba
    """The decimal digits of ``v`` >= 0; returns the position after them."""
    if v < 10:
        buf[pos] = 48 + v
        return pos + 1
    if v < 100:
        buf[pos] = PAIRS[2 * v]
        buf[pos + 1] = PAIRS[2 * v + 1]
        return pos + 2
    end = pos + _ndigits(v)
    p = end
    while p - pos >= 2:
        r = 2 * (v % 100)
        v //= 100
        buf[p - 1] = PAIRS[r + 1]
        buf[p - 2] = PAIRS[r]
        p -= 2
    if p > pos:
        buf[pos] = 48 + v
    return end


@njit(cache=True, inline="always")
def _decimals(buf, pos, f, dec):  # pragma: no cover - numba
    """``.`` and exactly ``dec`` digits of ``0 <= f < 10^dec`` (zero-padded); returns the position after them."""
    buf[pos] = 46
    p = pos + 1 + dec
    k = dec
    while k >= 2:
        r = 2 * (f % 100)
        f //= 100
        buf[p - 1] = PAIRS[r + 1]
        buf[p - 2] = PAIRS[r]
        p -= 2
        k -= 2
    if k:
        buf[p - 1] = 48 + f
    return pos + 1 + dec


@njit(cache=True, inline="always")
def _fixed(buf, pos, q, dec, scale, inv):  # pragma: no cover - numba
    """``q`` >= 0 as ``<q // scale>.<q % scale>`` (``scale = 10^dec`` = 1 / ``inv``; no ``.`` for
    ``dec`` 0): the integer part from the float quotient, corrected."""
    if dec == 0:
        return _uint(buf, pos, q)
    ip = np.int64(q * inv)
    f = q - ip * scale
    while f < 0:
        ip -= 1
        f += scale
    while f >= scale:
        ip += 1
        f -= scale
    return _decimals(buf, _uint(buf, pos, ip), f, dec)


@njit(cache=True, inline="always")
def _text(buf, pos, s):  # pragma: no cover - numba
    for i in range(s.size):
        buf[pos + i] = s[i]
    return pos + s.size


@njit(cache=True)
def rows_into(buf, t_ns, cols, kinds, decs, nan, inf, pow10, starts, e_prev):  # pragma: no cover - numba
    """Write the CSV text (uint8) of the rows into ``buf`` from 0; returns its length: ``t_ns`` (N,)
    int64 (stamp, exact), then ``cols`` (N, m) with ``kinds`` / ``decs`` (m,) per column,
    comma-separated, one line per row.  ``pow10``, ``starts``: :func:`pow10_table`,
    :func:`log10_floor_starts`; ``e_prev`` (m,) int64: per EXP column the last exponent's floor (a
    start of the search; updated).  ``buf`` needs ``N * max_line_bytes(m)`` bytes."""
    n, m = cols.shape
    scales = np.empty(m, np.int64)
    fscales = np.empty(m)
    inv = np.empty(m)
    for j in range(m):
        s = np.int64(1)
        for _ in range(decs[j]):
            s *= 10
        scales[j] = s
        fscales[j] = float(s)
        inv[j] = 1.0 / float(s)
    pos = 0
    for i in range(n):
        t = t_ns[i]
        if t < 0:
            buf[pos] = 45
            pos += 1
            t = -t
        pos = _decimals(buf, _uint(buf, pos, t // 1_000_000_000), t % 1_000_000_000, 9)
        for j in range(m):
            buf[pos] = 44
            pos += 1
            v = cols[i, j]
            if np.isnan(v):
                pos = _text(buf, pos, nan)
                continue
            neg = v < 0.0 or (v == 0.0 and np.signbit(v))
            if np.isinf(v):
                if neg:
                    buf[pos] = 45
                    pos += 1
                pos = _text(buf, pos, inf)
                continue
            a = -v if neg else v
            kind = kinds[j]
            if kind != EXP and a * fscales[j] >= 9.2e18:  # beyond int64 (a diverged solution): as %e, a number still
                kind = EXP  # (np.savetxt would print every digit of a %f, up to 300 and more)
            if kind == INT:
                q = np.int64(np.floor(a + 0.5))
                if neg and q != 0:
                    buf[pos] = 45
                    pos += 1
                pos = _uint(buf, pos, q)
                continue
            if neg:
                buf[pos] = 45
                pos += 1
            dec = decs[j]
            scale = scales[j]
            if kind == FIXED:
                q = np.int64(np.floor(a * fscales[j] + 0.5))
                pos = _fixed(buf, pos, q, dec, scale, inv[j])
                continue
            e = 0  # EXP: d.dddde+XX
            if a > 0.0:
                k = e_prev[j] - E_MIN  # floor(log10(a)) - E_MIN: starts[k] <= a < starts[k + 1]
                while k > 0 and a < starts[k]:
                    k -= 1
                while k < starts.size - 1 and a >= starts[k + 1]:
                    k += 1
                e_prev[j] = k + E_MIN
                e = k + E_MIN
                m_ = a / pow10[e - E_MIN]
                if m_ < 1.0:
                    e -= 1
                    m_ = a / pow10[e - E_MIN]
                elif m_ >= 10.0:
                    e += 1
                    m_ = a / pow10[e - E_MIN]
                q = np.int64(np.floor(m_ * fscales[j] + 0.5))
                if q >= 10 * scale:
                    q //= 10
                    e += 1
            else:
                q = np.int64(0)
            pos = _fixed(buf, pos, q, dec, scale, inv[j])
            buf[pos] = 101
            buf[pos + 1] = 45 if e < 0 else 43
            ae = -e if e < 0 else e
            if ae < 10:
                buf[pos + 2] = 48
                buf[pos + 3] = 48 + ae
                pos += 4
            else:
                pos = _uint(buf, pos + 2, ae)
        buf[pos] = 10
        pos += 1
    return pos


def max_line_bytes(m: int) -> int:
    """An upper bound of a row's bytes with ``m`` columns after the stamp (a number takes at most
    ~32 characters here)."""
    return 32 + 36 * m
