"""A platform's truth as the ``fixstream mc`` plugins score against it: picked from the events, aligned to stamps.

:func:`truths_of` gives the ``Truth`` messages of one platform (on ``fixstream/truth/<platform>``) in event order;
:func:`linear_at` gives a sampled series at other stamps: the sample itself at its stamp, linear in between,
NaN outside the sampled span.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from schemas import Truth
from shared import keys

from .events import Event

F64 = npt.NDArray[np.float64]


def truths_of(events: Iterable[Event], platform: str) -> list[Truth]:
    """The platform's ``Truth`` messages on its truth key, in event order."""
    key = keys.truth(platform)
    return [ev.msg for ev in events if ev.key == key and isinstance(ev.msg, Truth)]


def linear_at(t_ns: npt.ArrayLike, values: npt.ArrayLike, stamps_ns: npt.ArrayLike) -> F64:
    """``values`` (n, C), sampled at the increasing stamps ``t_ns`` (n,), at ``stamps_ns`` (m,): (m, C), exact at
    a sample's stamp, linear between samples, NaN outside ``[t_ns[0], t_ns[-1]]`` (everywhere if n = 0)."""
    t = np.asarray(t_ns, dtype=np.float64)
    q = np.asarray(stamps_ns).astype(np.float64)
    x = np.asarray(values, dtype=np.float64).reshape(t.size, -1)
    out = np.full((q.size, x.shape[1]), np.nan)
    if t.size == 0:
        return out
    inside = (q >= t[0]) & (q <= t[-1])
    for c in range(x.shape[1]):
        out[inside, c] = np.interp(q[inside], t, x[:, c])
    return out
