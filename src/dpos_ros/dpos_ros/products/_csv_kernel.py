"""Numba kernel of the antenna CSV rows (:func:`dpos_ros.products.ta.write_csv_rows`).

``np.savetxt`` formats every number through Python's ``%`` (~0.7 us each: 0.9 s for one
paper_wing antenna, 60 000 rows x 20 columns; a 4-hour flight's twelve antennas would take 9
minutes).  Here the digits are written into a byte buffer directly.  Column kinds: ``FIXED``
(``%.<d>f``), ``EXP`` (``%.<d>e``), ``INT`` (``%d``); the stamp column is written exactly from the
integer nanoseconds (``<s>.<9 digits>``).  Rounding is to nearest of the value scaled by
``10^d`` (printf rounds the exact binary value: the two can differ in the last digit only for a
value within a few ulps of a tie); NaN and infinities print as ``nan``, ``inf``, ``-inf``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

FIXED, EXP, INT = 0, 1, 2


@njit(cache=True)
def _uint(buf, pos, v, width):  # pragma: no cover - numba
    """The decimal digits of ``v`` >= 0, zero-padded to at least ``width``."""
    n, w = 1, v // 10
    while w > 0:
        n += 1
        w //= 10
    if n < width:
        n = width
    for i in range(n - 1, -1, -1):
        buf[pos + i] = 48 + v % 10
        v //= 10
    return pos + n


@njit(cache=True)
def _text(buf, pos, s):  # pragma: no cover - numba
    for i in range(s.size):
        buf[pos + i] = s[i]
    return pos + s.size


@njit(cache=True)
def _number(buf, pos, v, kind, dec, nan, inf):  # pragma: no cover - numba
    if np.isnan(v):
        return _text(buf, pos, nan)
    neg = v < 0.0 or (v == 0.0 and np.signbit(v))
    if np.isinf(v):
        if neg:
            buf[pos] = 45
            pos += 1
        return _text(buf, pos, inf)
    a = -v if neg else v
    if kind == INT:
        q = np.int64(np.floor(a + 0.5))
        if neg and q != 0:
            buf[pos] = 45
            pos += 1
        return _uint(buf, pos, q, 1)
    if neg:
        buf[pos] = 45
        pos += 1
    scale = np.int64(10) ** dec
    if kind == FIXED:
        q = np.int64(np.floor(a * scale + 0.5))
        pos = _uint(buf, pos, q // scale, 1)
        if dec > 0:
            buf[pos] = 46
            pos = _uint(buf, pos + 1, q % scale, dec)
        return pos
    e = 0  # EXP: d.dddde+XX
    if a > 0.0:
        e = int(np.floor(np.log10(a)))
        m = a / 10.0**e
        if m < 1.0:
            e -= 1
            m = a / 10.0**e
        elif m >= 10.0:
            e += 1
            m = a / 10.0**e
        q = np.int64(np.floor(m * scale + 0.5))
        if q >= 10 * scale:
            q //= 10
            e += 1
    else:
        q = np.int64(0)
    pos = _uint(buf, pos, q // scale, 1)
    if dec > 0:
        buf[pos] = 46
        pos = _uint(buf, pos + 1, q % scale, dec)
    buf[pos] = 101
    buf[pos + 1] = 45 if e < 0 else 43
    return _uint(buf, pos + 2, -e if e < 0 else e, 2)


@njit(cache=True)
def rows(t_ns, cols, kinds, decs, nan, inf):  # pragma: no cover - numba
    """The CSV text (bytes, uint8) of the rows: ``t_ns`` (N,) int64 (stamp, exact), then ``cols``
    (N, m) with ``kinds`` / ``decs`` (m,) per column, comma-separated, one line per row."""
    n, m = cols.shape
    buf = np.empty(n * (32 + 36 * m), np.uint8)  # a number takes at most ~32 characters here
    pos = 0
    for i in range(n):
        t = t_ns[i]
        if t < 0:
            buf[pos] = 45
            pos += 1
            t = -t
        pos = _uint(buf, pos, t // 1_000_000_000, 1)
        buf[pos] = 46
        pos = _uint(buf, pos + 1, t % 1_000_000_000, 9)
        for j in range(m):
            buf[pos] = 44
            pos = _number(buf, pos + 1, cols[i, j], kinds[j], decs[j], nan, inf)
        buf[pos] = 10
        pos += 1
    return buf[:pos]
