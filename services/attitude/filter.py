"""The second-order Kalman filter of eq. (3): predict with B and M, update with the converted plot, on the filter
toolkit (``shared.filters.kalman``).

The update uses the Joseph form and symmetrises the covariance (§5.6 "covariance hygiene"); the innovation
covariance enters through its Cholesky factor, never an explicit inverse (``kalman.update_selection``).

Notation: the digest writes R (R_alpha, R~, R_n) for the covariance of the state alpha and R_z for that of the
converted plot; the code and the toolkit use FilterPy's symbols (``shared/filters/__init__.py``):

==================  ==========================  =========
digest 004          meaning                     here
==================  ==========================  =========
alpha, alpha~       state, predicted state      x
R_alpha, R~, R_n    state covariance            P (``p``)
B                   transition                  F
M = S^T D_a S       random-manoeuvre noise      Q
H                   picks the positions         H = I[POS]
R_z (R_xyz)         converted-plot covariance   R (``rz``)
nu                  innovation                  y
==================  ==========================  =========
"""

from __future__ import annotations

from functools import lru_cache

from shared.filters import kalman

from .geometry import F64
from .models import POS, process_noise, transition


@lru_cache(maxsize=256)
def _model(dt_s: float, d_a: tuple[float, float, float]) -> tuple[F64, F64]:
    b = transition(dt_s)
    m = process_noise(dt_s, d_a)
    b.setflags(write=False)
    m.setflags(write=False)
    return b, m


def predict(x: F64, p: F64, dt_s: float, d_a: tuple[float, float, float], symmetrise: bool = True) -> tuple[F64, F64]:
    """x~ = B x, P~ = B P B^T + M over dt_s (any sign; the actual dt, never the nominal T).

    ``symmetrise=False`` skips the final symmetrisation when an update (which symmetrises) follows at once.
    """
    b, m = _model(float(dt_s), d_a)
    return kalman.predict(x, p, b, m, symmetrise=symmetrise)


def update(x_pred: F64, p_pred: F64, z: F64, rz: F64) -> tuple[F64, F64, float]:
    """Kalman update with a position measurement (eq. 3, Joseph form); returns (x, P, NIS). The state may
    extend the 9-state of eq. (3) by components after the ninth (the IMM's turn rate); H picks the positions.

    S = H P~ H^T + R_z is factorised S = L L^T (Cholesky); K = P~ H^T L^-T L^-1 and NIS = |L^-1 nu|^2
    (``kalman.update_selection``). Raises numpy.linalg.LinAlgError if S is not positive definite.
    """
    x, p, _, nis = kalman.update_selection(x_pred, p_pred, z, POS, rz)
    return x, p, nis
