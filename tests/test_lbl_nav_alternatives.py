"""The two-filter sequential alternative (KF + KF) reaches the single-filter estimate (digest 000, 2.6, 3.1.6)."""

from __future__ import annotations

import numpy as np
import pytest
from test_lbl_nav_units import forward_reference_after, linear_case

from services.lbl_nav.alternatives import TwoFilterScheme


@pytest.mark.parametrize("dN0,dN", [(0, 10), (5, 3)])
def test_two_filter_scheme_equals_the_forward_reference_in_the_linear_case(dN0: int, dN: int) -> None:
    case = linear_case(dN0, dN)
    kk = TwoFilterScheme(case["cfg"], case["X0"], case["P0"], case["buf"], case["drs"][0])
    kk.launch_steps()
    i = 0
    while kk.catching_up or i == 0:
        i += 1
        kk.epoch_step(case["drs"][i], case["current"][i])
    Xr, Pr = forward_reference_after(case, i)
    sig = np.sqrt(np.diag(Pr))
    # the backward filter's prior is diffuse but finite (1e10 m^2 ...), hence 1e-2 sigma rather than 1e-3
    assert np.all(np.abs(kk.X_fused - Xr) <= 1e-2 * sig), (kk.X_fused - Xr) / sig
    assert np.allclose(kk.P_fused, Pr, rtol=1e-2, atol=1e-6 * np.abs(Pr).max())
    # and it keeps tracking with the fused state afterwards
    kk.epoch_step(case["drs"][i + 1], case["current"][i + 1])
    Xr2, _ = forward_reference_after(case, i + 1)
    assert np.all(np.abs(kk.X_fused - Xr2) <= 1e-2 * sig)
