"""Cramér-Rao bound of the vertical channel of terrain_nav (issue 16, AT-15), independent of the estimator.

The simulator (``services/terrain_nav/simulation.py``) draws, per raw radio-altimeter sample k at time t_k and
true position p_k = p_ins,k + d(t_k):

    h_ra,k = h_true,k - T(p_k) + v_k,          v_k ~ N(0, sigma_v^2) white,
    DEM[c] = T_c + eps_c,                       eps_c ~ N(0, sigma_map^2) white per map cell,

T the bilinear interpolant through the truth cell centres T_c. Eliminating the unknown truth T_c with the DEM
(T = B(DEM) - B(eps), B the bilinear weights W) gives the data model the estimator faces,

    y_k = h_ins,k - h_ra,k + B(DEM)(p_k) ... = mu_k(theta) + w_k,   w = v - W eps,
    Sigma = sigma_v^2 I + sigma_map^2 W W^T    (samples sharing a cell share its map error),

so the Fisher information of the unknowns theta is ``J = G^T Sigma^-1 G`` with ``G = d mu / d theta`` at the
truth. The unknowns (all at the fix time t_f, tau = t_k - t_f):

* the horizontal offset (dx, dz): column ``-grad T(p_k)`` (finite differences of the *truth* interpolant at the
  true positions),
* the vertical errors of the digest's model (eq. 3, the simulator's dh(t) = dh0 + dV0 t + da t^2/2):
  dh (column 1), dV (tau), da (tau^2/2),
* optionally the horizontal velocity errors (dvx, dvz): ``-grad T * tau`` (the offset drifts in the window),
  with the simulator's N(0, sigma_vh) prior on them (a Bayesian bound: the estimator assumes no drift).

The bound on the variance of any unbiased estimate of dh(t_f) from those samples is ``[J^-1]_hh``. Sigma^-1 is
applied by the Woodbury identity (W has one column per touched cell, so the inner system is small); a dense
solve is kept for the tests to compare against.

``python -m bench.terrain_vertical_bound --runs N [--family NAME] [--out F.json]`` runs the bench's terrain
families (``bench_terrain_families``, same seeds) with the robust and paper presets and compares, over the
fixes with N_valid >= N_max (AT-15's accuracy part), the estimator's |dh error| with the bound: the bound's
own median / p95 of |N(0, CRLB_i)| over the same fixes (quantiles of the mixture), and MSE / mean CRLB.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq
from scipy.stats import norm


@dataclass(frozen=True)
class SampleSet:
    """Raw samples entering one bound: times (s), terrain gradient at the true positions (m/m, per axis) and the
    bilinear weights of each sample on the map cells: ``ci``, ``cj``, ``w`` of shape (n, m), sample k putting
    weight ``w[k, q]`` on cell (``ci[k, q]``, ``cj[k, q]``); zero weights are ignored."""

    t: np.ndarray
    gx: np.ndarray
    gz: np.ndarray
    ci: np.ndarray
    cj: np.ndarray
    w: np.ndarray


DEFAULT_UNKNOWNS = ("dx", "dz", "dh", "dV", "da")
DRIFT_UNKNOWNS = ("dx", "dz", "dvx", "dvz", "dh", "dV", "da")


def design(s: SampleSet, t_fix: float, unknowns: Sequence[str] = DEFAULT_UNKNOWNS) -> tuple[np.ndarray, list[str]]:
    """G (n x p): d mu_k / d theta for the named unknowns (dx, dz, dvx, dvz, dh, dV, da), all at t_fix."""
    tau = s.t - t_fix
    columns = {
        "dx": -s.gx,
        "dz": -s.gz,
        "dvx": -s.gx * tau,
        "dvz": -s.gz * tau,
        "dh": np.ones_like(tau),
        "dV": tau,
        "da": 0.5 * tau * tau,
    }
    names = list(unknowns)
    return np.stack([columns[k] for k in names], axis=1), names


def weight_matrix(s: SampleSet) -> np.ndarray:
    """W (n x cells): the bilinear weight of sample k on each touched map cell."""
    keep = s.w != 0.0
    rows = np.broadcast_to(np.arange(s.w.shape[0])[:, None], s.w.shape)[keep]
    cells, col = np.unique(np.stack([s.ci[keep], s.cj[keep]], axis=1), axis=0, return_inverse=True)
    W = np.zeros((s.w.shape[0], cells.shape[0]))
    np.add.at(W, (rows, col.ravel()), s.w[keep])
    return W


def fisher(G: np.ndarray, W: np.ndarray, sigma_v: float, sigma_map: float) -> np.ndarray:
    """G^T Sigma^-1 G, Sigma = sigma_v^2 I + sigma_map^2 W W^T, by Woodbury:
    Sigma^-1 = (I - W (r I + W^T W)^-1 W^T) / sigma_v^2 with r = sigma_v^2 / sigma_map^2."""
    GtG = G.T @ G
    if sigma_map == 0.0 or W.shape[1] == 0:
        out: np.ndarray = GtG / sigma_v**2
        return out
    r = sigma_v**2 / sigma_map**2
    A = r * np.eye(W.shape[1]) + W.T @ W
    WtG = W.T @ G
    out = (GtG - WtG.T @ np.linalg.solve(A, WtG)) / sigma_v**2
    return out


def fisher_dense(G: np.ndarray, W: np.ndarray, sigma_v: float, sigma_map: float) -> np.ndarray:
    """The same with the full n x n covariance (a check of :func:`fisher`)."""
    Sigma = sigma_v**2 * np.eye(G.shape[0]) + sigma_map**2 * (W @ W.T)
    out: np.ndarray = G.T @ np.linalg.solve(Sigma, G)
    return out


def crlb(J: np.ndarray, names: list[str], which: str = "dh", prior: dict[str, float] | None = None) -> float:
    """[(J + prior information)^-1] of ``which``; ``prior`` maps names to prior sigmas (a Bayesian bound)."""
    J = J.copy()
    for k, sig in (prior or {}).items():
        if k in names:
            J[names.index(k), names.index(k)] += 1.0 / sig**2
    i = names.index(which)
    e = np.zeros(len(names))
    e[i] = 1.0
    try:
        return float(np.linalg.solve(J, e)[i])
    except np.linalg.LinAlgError:
        return math.inf


def flight_samples(flight: Any, t_from: float, t_to: float, fd_step_m: float = 0.5) -> SampleSet:
    """Valid raw samples of a simulated flight with scenario time in [t_from, t_to]: the truth's gradient
    (central differences of the truth interpolant) and the bilinear weights on the reference map's cells."""
    t = flight.t
    ok = (t >= t_from - 1e-9) & (t <= t_to + 1e-9) & flight.ra_valid & flight.ins_present & np.isfinite(flight.h_ra)
    x, z = flight.x_true[ok], flight.z_true[ok]
    w = flight.world
    h = fd_step_m
    gx = (w.terrain_height(x + h, z) - w.terrain_height(x - h, z)) / (2 * h)
    gz = (w.terrain_height(x, z + h) - w.terrain_height(x, z - h)) / (2 * h)
    x0, z0, cell = w.truth_geometry
    ref = w.ref_map
    # the map error lives on the reference map's cells; the truth grid is the map's plus a margin
    off_i = round((ref.x0_m - x0) / cell)
    off_j = round((ref.z0_m - z0) / cell)
    u = (x - x0) / cell - 0.5
    v = (z - z0) / cell - 0.5
    i0, j0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = u - i0, v - j0
    n_i, n_j = ref.shape
    ci = np.stack([i0, i0 + 1, i0, i0 + 1], axis=1) - off_i
    cj = np.stack([j0, j0, j0 + 1, j0 + 1], axis=1) - off_j
    wt = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=1)
    on_map = (ci >= 0) & (ci < n_i) & (cj >= 0) & (cj < n_j)  # margin cells carry no map error
    return SampleSet(t=t[ok], gx=gx, gz=gz, ci=ci, cj=cj, w=np.where(on_map, wt, 0.0))


def fix_bound(
    flight: Any,
    t_from: float,
    t_to: float,
    t_fix: float,
    unknowns: Sequence[str] = DEFAULT_UNKNOWNS,
    prior: dict[str, float] | None = None,
) -> float:
    """CRLB of dh(t_fix) (m^2) from the flight's samples in [t_from, t_to] under the simulator's noise."""
    return fix_bounds(flight, t_from, t_to, t_fix, {"b": (unknowns, prior)})["b"]


def fix_bounds(
    flight: Any,
    t_from: float,
    t_to: float,
    t_fix: float,
    variants: dict[str, tuple[Sequence[str], dict[str, float] | None]],
) -> dict[str, float]:
    """:func:`fix_bound` for several (unknowns, prior) variants over the same samples."""
    s = flight_samples(flight, t_from, t_to)
    W = weight_matrix(s)
    sc = flight.scenario
    out = {}
    for name, (unknowns, prior) in variants.items():
        G, names = design(s, t_fix, unknowns)
        out[name] = crlb(fisher(G, W, sc.sigma_v_m, sc.sigma_map_m), names, "dh", prior)
    return out


def bound_variants(sc: Any) -> dict[str, tuple[Sequence[str], dict[str, float] | None]]:
    """The bounds the bench reports, over the window's samples: ``crlb`` (dx, dz, dh, dV, da; no prior: any
    unbiased estimator), ``bayes`` (the same with the simulator's N(0, sigma_da) prior on da, a Bayesian bound on
    any estimator's mean squared error; the estimator's own P0 carries a prior on da too) and ``drift_bayes``
    (plus the horizontal velocity errors with their N(0, sigma_vh) prior)."""
    da = {"da": sc.sigma_da_mps2} if sc.sigma_da_mps2 > 0 else {}
    dv = {"dvx": sc.sigma_vh_mps, "dvz": sc.sigma_vh_mps} if sc.sigma_vh_mps > 0 else {}
    return {"crlb": (DEFAULT_UNKNOWNS, None), "bayes": (DEFAULT_UNKNOWNS, da), "drift_bayes": (DRIFT_UNKNOWNS, da | dv)}


def mixture_abs_quantile(var: np.ndarray, p: float) -> float:
    """q with mean_i P(|N(0, var_i)| <= q) = p: the p-quantile of |error| for an estimator at the bound."""
    sd = np.sqrt(np.asarray(var, dtype=np.float64))

    def cdf(q: float) -> float:
        return float(np.mean(2.0 * norm.cdf(q / sd) - 1.0)) - p

    return float(brentq(cdf, 0.0, 20.0 * float(sd.max()) + 1e-9))


@dataclass
class BoundTally:
    """Fixes with N_valid >= N_max: the estimator's dh errors and the per-fix bounds (``bound_variants`` over the
    window's samples; ``to_date_bayes``: ``bayes`` over every sample since the start, the data the grid filter
    uses)."""

    err: list[float] = field(default_factory=list)
    bounds: dict[str, list[float]] = field(default_factory=dict)

    def row(self) -> dict[str, Any]:
        if not self.err:
            return {"n": 0}
        e = np.abs(np.asarray(self.err))
        out: dict[str, Any] = {
            "n": int(e.size),
            "median_m": float(np.median(e)),
            "p95_m": float(np.percentile(e, 95)),
            "mse_m2": float(np.mean(e * e)),
            "bias_m": float(np.mean(self.err)),
        }
        for key, v in self.bounds.items():
            a = np.asarray(v)
            out[key] = {
                "median_m": mixture_abs_quantile(a, 0.5),
                "p95_m": mixture_abs_quantile(a, 0.95),
                "mean_crlb_m2": float(a.mean()),
                "mse_over_mean_crlb": out["mse_m2"] / float(a.mean()),
            }
        return out


def score_bound(
    flight: Any,
    msgs: list[Any],
    cfg: Any,
    t: BoundTally,
    to_date: bool = True,
    cache: dict[tuple[float, float, float, bool], dict[str, float]] | None = None,
) -> None:
    """Run the navigator over the flight; at each fix with N_valid >= N_max, its dh error and the bounds
    (``cache``: bounds already computed for this flight, by window and fix time)."""
    from bench.bench_terrain_families import navigator_outputs
    from schemas.terrain_nav import TerrainFix
    from services.terrain_nav.core import TerrainNavigator

    nav = TerrainNavigator(flight.world.ref_map, cfg)
    t_start = float(flight.t[0])
    variants = bound_variants(flight.scenario)
    if cache is None:
        cache = {}
    for m in navigator_outputs(nav, msgs):
        if not isinstance(m, TerrainFix) or m.verdict.n_valid < m.verdict.n_max:
            continue
        t_fix = m.header.stamp_ns * 1e-9
        dh = m.vertical.index("dh")
        t.err.append(m.vertical.mean[dh] - flight.truth_at(t_fix)["dh"])
        measq = nav.window.measq
        t_first, t_last = measq[0].t_first, measq[-1].t_last
        key = (t_first, t_last, t_fix, to_date)
        if key not in cache:  # the same fix of another preset over the same flight
            cache[key] = fix_bounds(flight, t_first, t_last, t_fix, variants)
            if to_date:
                got_to_date = fix_bounds(flight, t_start, t_last, t_fix, {"b": variants["bayes"]})["b"]
                cache[key] |= {"to_date_bayes": got_to_date}
        got = cache[key]
        for k, v in got.items():
            t.bounds.setdefault(k, []).append(v)


def run(
    families: list[str] | None,
    runs: int,
    presets: list[str],
    seed0: int = 16,
    on_run: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    from bench.bench_terrain_families import FAMILIES, family_flight, preset_config

    out: dict[str, Any] = {}
    for fam in FAMILIES:
        if families and not any(fam.name.startswith(f) for f in families):
            continue
        tallies = {p: BoundTally() for p in presets}
        t0 = time.time()
        for r in range(runs):  # the bench's seeding: the same worlds and flights
            flight, msgs = family_flight(fam, seed0, r)
            cache: dict[tuple[float, float, float, bool], dict[str, float]] = {}
            for p in presets:
                score_bound(flight, msgs, preset_config(p), tallies[p], cache=cache)
            out[fam.name] = {p: {"runs": r + 1, **tl.row()} for p, tl in tallies.items()}
            if on_run is not None:
                on_run(out)
        for p, row in out.get(fam.name, {}).items():
            print(f"{fam.name:28s} {p:8s} {json.dumps(row)} [{time.time() - t0:.0f}s]", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.terrain_vertical_bound")
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--family", action="append")
    ap.add_argument("--preset", action="append")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)

    def dump(out: dict[str, Any]) -> None:
        if a.out:
            with open(a.out, "w") as fh:
                json.dump(out, fh, indent=1)

    dump(run(a.family, a.runs, a.preset or ["robust", "paper"], on_run=dump))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
