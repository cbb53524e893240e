"""The PCL tracker core: one instance = one receiver–illuminator pair (digest 003 §5).

``PclTracker.step(msg)`` takes a :class:`~schemas.radar.BistaticScan` or a
:class:`~schemas.radar.BistaticConfigUpdate` and returns the :class:`~schemas.pcl_tracker.PclScanReport`
messages it produced (usually one; zero while a scan waits in the reorder buffer; several when the buffer
is released). Inputs it refuses raise :class:`shared.service.InputRejected`; the state stays valid.
Processing follows the reference order of §5.5; there is no I/O and no wall clock: time is
``header.stamp_ns`` of the scan.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from schemas.base import Header
from schemas.pcl_tracker import PclScanReport, PclTrackReport
from schemas.radar import BistaticConfigUpdate, BistaticScan
from shared.service import InputRejected

from .association import assign_gnn, assign_nn, gate_matrix
from .config import PclTrackerConfig
from .filter import (
    ConvertedPlots,
    bistatic_image,
    bkf_measurement,
    bkf_predict,
    bkf_update,
    convert_plots,
    kf_position_update,
    predict,
    ukf_bistatic_update,
)
from .geometry import BoolArray, FloatArray
from .initiation import bistatic_to_cartesian, ring_ellipse_test, two_plot_bistatic_estimate, ukf_only_init
from .models import plot_covariance
from .plots import NormalisedPlots, normalise_plots
from .ut import CholeskyStats, TransformResult, symmetrize

_DEG = 180.0 / math.pi
_BISTATIC_UNITS = np.array([1.0, _DEG, _DEG, 1.0])


@dataclass
class TrackState:
    """Everything kept per track (digest §5.4). ``x``/``P`` are x_a (phase "ukf") or x_b (phase "bkf")."""

    track_id: int
    status: str
    phase: str
    x: FloatArray
    P: FloatArray
    t_ns: int
    created_scan: int
    hits: int = 2
    misses: int = 0
    mn_hits: int = 0
    mn_scans: int = 0


@dataclass
class Candidate:
    """A first plot awaiting a partner (digest §5.4)."""

    plot_id: str
    scan_id: int
    t_ns: int
    z: FloatArray  # (4,) [r_b, a, e, v_b]
    sig: FloatArray  # (4,)
    zc: FloatArray  # (3,) converted position
    Rc: FloatArray  # (3, 3)


@dataclass
class _ScanWork:
    """Per-scan bookkeeping used to build the report."""

    flags: list[str] = field(default_factory=list)
    finals: list[PclTrackReport] = field(default_factory=list)
    assoc: dict[int, tuple[str, float]] = field(default_factory=dict)
    in_gate: dict[int, int] = field(default_factory=dict)
    track_flags: dict[int, list[str]] = field(default_factory=dict)
    updated: set[int] = field(default_factory=set)
    created: set[int] = field(default_factory=set)
    drops: Counter[str] = field(default_factory=Counter)
    images: dict[int, TransformResult] = field(default_factory=dict)
    chol: CholeskyStats = field(default_factory=CholeskyStats)


class PclTracker:
    """Passive coherent locator tracker: bistatic association, Cartesian UKF, 2/L initiation, M/N confirmation."""

    def __init__(self, config: PclTrackerConfig | None = None) -> None:
        self.config = config or PclTrackerConfig()
        geo = self.config.geometry
        self.receiver_id = geo.receiver_id
        self.illuminator_id = geo.illuminator_id
        self.tx = np.array(geo.tx_position_enu_m, dtype=np.float64)
        self.L_m = float(np.linalg.norm(self.tx))
        self.wavelength_m = geo.wavelength_m
        self.gamma4 = self.config.tracker.gamma4
        self.gamma3 = self.config.tracker.gamma3
        self.tracks: dict[int, TrackState] = {}
        self.candidates: list[Candidate] = []
        self.next_track_id = 1
        self.last_scan_id: int | None = None
        self.last_t_ns: int | None = None
        self._buffer: dict[int, BistaticScan] = {}
        self._skipped: set[int] = set()
        self._recent: dict[int, BistaticScan] = {}
        self._pending_flags: list[str] = []
        self._counts_history: list[int] = []
        #: running metrics (digest §5.7)
        self.metrics: Counter[str] = Counter()

    # ------------------------------------------------------------------------------------------ public API
    def step(self, msg: BistaticScan | BistaticConfigUpdate) -> list[PclScanReport]:
        """Process one input message; return the scan reports it produced."""
        if isinstance(msg, BistaticConfigUpdate):
            return self._on_config(msg)
        if isinstance(msg, BistaticScan):
            return self._on_scan(msg)
        raise InputRejected("wrong_type", f"unsupported input {type(msg).__name__}")

    def flush(self) -> list[PclScanReport]:
        """Process every buffered scan in scan_id order (end of stream)."""
        out: list[PclScanReport] = []
        for sid in sorted(self._buffer):
            scan = self._buffer.pop(sid)
            out.extend(self._process_checked(scan))
        return out

    def predict(self, track_id: int, stamp_ns: int) -> PclTrackReport:
        """[D] On-demand extrapolation of a live track to ``stamp_ns`` (no state change)."""
        tr = self.tracks.get(track_id)
        if tr is None:
            raise KeyError(track_id)
        tau = np.array([(stamp_ns - tr.t_ns) * 1e-9])
        work = _ScanWork()
        ghost = TrackState(**{**tr.__dict__, "x": tr.x.copy(), "P": tr.P.copy()})
        self._predict_tracks([ghost], tau)
        ghost.t_ns = stamp_ns
        scan_id = self.last_scan_id if self.last_scan_id is not None else 0
        return self._track_reports([ghost], scan_id, stamp_ns, work, None)[0]

    # ------------------------------------------------------------------------------------------ config
    def _check_pair(self, receiver_id: str, illuminator_id: str) -> None:
        if receiver_id != self.receiver_id or illuminator_id != self.illuminator_id:
            raise InputRejected(
                "wrong_pair",
                f"{receiver_id}/{illuminator_id} is not this tracker's pair {self.receiver_id}/{self.illuminator_id}",
            )

    def _on_config(self, msg: BistaticConfigUpdate) -> list[PclScanReport]:
        self._check_pair(msg.receiver_id, msg.illuminator_id)
        tx = np.array(msg.tx_position_enu_m, dtype=np.float64)
        if not np.all(np.isfinite(tx)):
            raise InputRejected("nan", "non-finite transmitter position")
        if msg.wavelength_m is not None:
            self.wavelength_m = msg.wavelength_m
        if np.array_equal(tx, self.tx):
            return []
        self.tx = tx
        self.L_m = float(np.linalg.norm(tx))
        work = _ScanWork(flags=["config_reset"])
        stamp = msg.header.stamp_ns
        scan_id = self.last_scan_id if self.last_scan_id is not None else 0
        self._reset(work, scan_id, stamp)
        self.metrics["config_resets"] += 1
        return [self._scan_report(scan_id, stamp, work, None, trigger="config")]

    # ------------------------------------------------------------------------------------------ ordering
    @staticmethod
    def _content(scan: BistaticScan) -> dict[str, Any]:
        """What makes two copies of a scan the same (publisher seq/source excluded)."""
        return scan.model_dump(exclude={"header": {"seq", "source"}})

    def _on_scan(self, scan: BistaticScan) -> list[PclScanReport]:
        self._check_pair(scan.receiver_id, scan.illuminator_id)
        sid = scan.scan_id
        last = self.last_scan_id
        if (last is not None and sid <= last) or sid in self._buffer:
            known = self._recent.get(sid) or self._buffer.get(sid)
            if known is not None:
                same = self._content(known) == self._content(scan)
                self.metrics["duplicate_scans"] += 1
                raise InputRejected(
                    "duplicate_scan", f"scan {sid} already seen ({'same' if same else 'different'} content)"
                )
            self._pending_flags.append("late_scan_dropped")
            self.metrics["late_scans"] += 1
            raise InputRejected("late_scan_dropped", f"scan {sid} arrived after scan {last} was processed")
        ref_t = self.last_t_ns
        if ref_t is not None and scan.header.stamp_ns <= ref_t:
            self._skipped.add(sid)
            self.metrics["time_not_monotonic"] += 1
            raise InputRejected("time_not_monotonic", f"scan {sid} stamp {scan.header.stamp_ns} <= {ref_t}")
        if last is None and not self._buffer:
            return self._process_checked(scan)
        self._buffer[sid] = scan
        return self._drain()

    def _drain(self) -> list[PclScanReport]:
        out: list[PclScanReport] = []
        window = self.config.limits.reorder_window_scans
        while self._buffer:
            first = min(self._buffer)
            last = self.last_scan_id
            nxt = (last + 1) if last is not None else first
            missing = [s for s in range(nxt, first) if s not in self._skipped]
            if first == nxt or not missing or len(self._buffer) > window:
                out.extend(self._process_checked(self._buffer.pop(first)))
            else:
                break
        return out

    def _process_checked(self, scan: BistaticScan) -> list[PclScanReport]:
        if self.last_t_ns is not None and scan.header.stamp_ns <= self.last_t_ns:
            # a buffered scan that turned out older than what was processed: drop it, flag the next report
            self._skipped.add(scan.scan_id)
            self._pending_flags.append("time_not_monotonic")
            self.metrics["time_not_monotonic"] += 1
            return []
        return [self._process(scan)]

    # ------------------------------------------------------------------------------------------ one scan
    def _process(self, scan: BistaticScan) -> PclScanReport:
        cfg = self.config
        trk, lim = cfg.tracker, cfg.limits
        sid = scan.scan_id
        t_ns = scan.header.stamp_ns
        work = _ScanWork(flags=list(dict.fromkeys(self._pending_flags)))
        self._pending_flags.clear()

        # 0. gap handling
        gap = 0 if self.last_scan_id is None else sid - self.last_scan_id - 1
        if gap > lim.max_gap_scans:
            work.flags.append("gap_reset")
            self._reset(work, sid, t_ns)
            self.metrics["gap_resets"] += 1
        elif gap > 0:
            work.flags.append("gap_coast")
            for tr in sorted(self.tracks.values(), key=lambda t: t.track_id):
                tr.misses += gap
                if tr.status == "TENTATIVE":
                    tr.mn_scans += gap
                self._maybe_drop(tr, work, sid, t_ns)
        self.last_scan_id = sid
        self.last_t_ns = t_ns
        self._recent[sid] = scan
        for old in [s for s in self._recent if s < sid - 16]:
            del self._recent[old]
        self._skipped = {s for s in self._skipped if s > sid}

        # validate / normalise plots
        plots = normalise_plots(scan.plots, cfg, self.L_m, self.wavelength_m)
        for k in plots.flagged:
            if k in ("sigma_defaulted", "near_baseline"):
                work.flags.append(k)
        n_valid = len(plots)
        suppress_init = self._burst(n_valid)
        if suppress_init:
            work.flags.append("clutter_burst")
            self.metrics["clutter_bursts"] += 1
        R_plot = plot_covariance(plots.sig)

        # 1. predict every live track and map the prediction to bistatic coordinates
        live = sorted(self.tracks.values(), key=lambda t: (t.status != "CONFIRMED", t.track_id))
        taus = np.array([(t_ns - tr.t_ns) * 1e-9 for tr in live])
        preds = self._predict_tracks(live, taus, work.chol)
        for tr in live:
            tr.t_ns = t_ns

        # 2. gating
        if live and n_valid:
            z_pred = np.stack([p.mean[0] for p in preds])
            R_pred = np.stack([p.cov[0] for p in preds])
            d2, logdet = gate_matrix(z_pred, R_pred, plots.z, R_plot)
        else:
            d2 = np.zeros((len(live), n_valid))
            logdet = np.zeros_like(d2)
        gated = d2 <= self.gamma4
        in_some_gate: BoolArray = np.asarray(gated.any(axis=0), dtype=bool) if live else np.zeros(n_valid, dtype=bool)
        for i, tr in enumerate(live):
            work.in_gate[tr.track_id] = int(gated[i].sum())

        # 3. assignment: confirmed tracks first, then tentative tracks with the remaining plots
        cost = d2 + (logdet if trk.gnn_cost_logdet else 0.0)
        assign = assign_gnn if trk.association == "gnn" else assign_nn
        pairs: list[tuple[int, int]] = []
        used = np.zeros(n_valid, dtype=bool)
        for group in ("CONFIRMED", "TENTATIVE"):
            rows = np.array([i for i, tr in enumerate(live) if tr.status == group], dtype=np.int64)
            if rows.size == 0 or n_valid == 0:
                continue
            g = gated[rows] & ~used[None, :]
            for r, c in assign(cost[rows], g):
                pairs.append((int(rows[r]), c))
                used[c] = True

        # plot conversions (UT n = 3), done once per plot and reused by update and initiation
        convertible = ~plots.low_rb
        need = np.zeros(n_valid, dtype=bool)
        for _, c in pairs:
            need[c] = True
        need |= ~in_some_gate
        need &= convertible
        conv_idx = np.flatnonzero(need)
        conv = convert_plots(plots.z[conv_idx, :3], plots.sig[conv_idx, :3], self.tx, trk.transform, work.chol)
        conv_of = {int(j): k for k, j in enumerate(conv_idx)}
        n_clamped = int(conv.clamped.sum())

        # 4. update assigned tracks; misses for the others
        assigned = {i: c for i, c in pairs}
        self._update_tracks(live, preds, assigned, plots, R_plot, conv, conv_of, d2, work)
        for i, tr in enumerate(live):
            if i in assigned:
                continue
            tr.misses += 1
            if tr.status == "TENTATIVE":
                tr.mn_scans += 1
            self._maybe_drop(tr, work, sid, t_ns, pred=preds[i])
        for i, tr in enumerate(live):
            if tr.track_id not in work.updated:
                work.images[tr.track_id] = preds[i]  # x(k|k) = x(k|k-1): reuse the inverse UT

        # 5. initiation
        n_init = 0
        if suppress_init:
            self.candidates = [c for c in self.candidates if sid - c.scan_id < trk.init_L - 1]
        else:
            p0 = [
                j
                for j in range(n_valid)
                if not in_some_gate[j] and convertible[j] and j in conv_of and bool(conv.valid[conv_of[j]])
            ]
            n_init = self._initiate(p0, plots, conv, conv_of, sid, t_ns, work)
        self._enforce_capacity(work, sid, t_ns)

        self._counts_history.append(n_valid)
        del self._counts_history[: -lim.burst_history_scans]
        report = self._scan_report(sid, t_ns, work, plots, trigger="scan")
        report = report.model_copy(
            update={
                "n_associated": len(pairs),
                "n_initiated": n_init,
                "gap_scans": max(gap, 0),
                "n_sigma_clamped": n_clamped,
                "n_plots_in": len(scan.plots),
            }
        )
        self.metrics["scans"] += 1
        self.metrics["plots_in"] += len(scan.plots)
        self.metrics["associated"] += len(pairs)
        self.metrics["initiated"] += n_init
        self.metrics["cholesky_fallbacks"] += work.chol.total
        for k, v in plots.rejected.items():
            self.metrics[f"rejected_{k}"] += v
        return report

    # ------------------------------------------------------------------------------------------ helpers
    def _burst(self, n: int) -> bool:
        lim = self.config.limits
        if n > lim.max_plots_per_scan:
            return True
        hist = self._counts_history[-lim.burst_history_scans :]
        if len(hist) < lim.burst_history_scans or n < lim.burst_min_plots:
            return False
        return n > lim.burst_factor * max(float(np.median(hist)), 1.0)

    def _predict_tracks(
        self, live: list[TrackState], taus: FloatArray, chol: CholeskyStats | None = None
    ) -> list[TransformResult]:
        """Predict every track in place; return its predicted bistatic measurement (batch of one each)."""
        trk = self.config.tracker
        out: list[TransformResult | None] = [None] * len(live)
        for phase in ("ukf", "bkf"):
            idx = [i for i, tr in enumerate(live) if tr.phase == phase]
            if not idx:
                continue
            X = np.stack([live[i].x for i in idx])
            P = np.stack([live[i].P for i in idx])
            if phase == "ukf":
                X, P = predict(X, P, taus[idx], trk.q_accel_var_m2s4)
                res = bistatic_image(X, P, self.tx, trk.transform, chol)
            else:
                X, P = bkf_predict(X, P, taus[idx], trk.bkf_q_r_m2s4, trk.bkf_q_ang_rad2s4)
                res = bkf_measurement(X, P)
            for k, i in enumerate(idx):
                live[i].x = X[k]
                live[i].P = P[k]
                out[i] = TransformResult(res.mean[k : k + 1], res.cov[k : k + 1], res.cross[k : k + 1])
        return [o for o in out if o is not None]

    def _update_tracks(
        self,
        live: list[TrackState],
        preds: list[TransformResult],
        assigned: dict[int, int],
        plots: NormalisedPlots,
        R_plot: FloatArray,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
        d2: FloatArray,
        work: _ScanWork,
    ) -> None:
        trk = self.config.tracker
        ukf_rows: list[tuple[int, int]] = []
        bkf_rows: list[tuple[int, int]] = []
        for i, c in assigned.items():
            tr = live[i]
            work.assoc[tr.track_id] = (plots.ids[c], float(d2[i, c]))
            if tr.phase == "bkf":
                bkf_rows.append((i, c))
            elif plots.low_rb[c]:
                work.track_flags.setdefault(tr.track_id, []).append("low_rb_hit")
            elif trk.measurement_model == "converted_position":
                if not bool(conv.valid[conv_of[c]]):
                    work.track_flags.setdefault(tr.track_id, []).append("conversion_failed")
                else:
                    ukf_rows.append((i, c))
            else:
                ukf_rows.append((i, c))
        if ukf_rows:
            ii = [i for i, _ in ukf_rows]
            cc = [c for _, c in ukf_rows]
            X = np.stack([live[i].x for i in ii])
            P = np.stack([live[i].P for i in ii])
            if trk.measurement_model == "converted_position":
                kk = [conv_of[c] for c in cc]
                X, P, _ = kf_position_update(X, P, conv.y[kk], conv.R[kk])
            else:
                pred = TransformResult(
                    np.concatenate([preds[i].mean for i in ii]),
                    np.concatenate([preds[i].cov for i in ii]),
                    np.concatenate([preds[i].cross for i in ii]),
                )
                X, P = ukf_bistatic_update(X, P, pred, plots.z[cc], R_plot[cc])
            for k, i in enumerate(ii):
                live[i].x, live[i].P = X[k], P[k]
                work.updated.add(live[i].track_id)
        if bkf_rows:
            ii = [i for i, _ in bkf_rows]
            cc = [c for _, c in bkf_rows]
            X = np.stack([live[i].x for i in ii])
            P = np.stack([live[i].P for i in ii])
            X, P = bkf_update(X, P, plots.z[cc], R_plot[cc])
            for k, i in enumerate(ii):
                live[i].x, live[i].P = X[k], P[k]
                work.updated.add(live[i].track_id)
        M = trk.confirm_M
        for i in sorted(assigned):
            tr = live[i]
            tr.hits += 1
            tr.misses = 0
            if tr.status == "TENTATIVE":
                tr.mn_hits += 1
                tr.mn_scans += 1
                if tr.mn_hits >= M:
                    self._confirm(tr, work.chol)

    def _confirm(self, tr: TrackState, chol: CholeskyStats | None) -> None:
        tr.status = "CONFIRMED"
        if tr.phase == "bkf" and self.config.tracker.scheme == "bkf_ukf":
            res = bistatic_to_cartesian(tr.x[None], tr.P[None], self.tx, self.config.tracker.transform, chol)
            tr.x, tr.P, tr.phase = res.mean[0], res.cov[0], "ukf"

    def _maybe_drop(
        self, tr: TrackState, work: _ScanWork, sid: int, t_ns: int, pred: TransformResult | None = None
    ) -> None:
        trk = self.config.tracker
        reason: str | None = None
        if tr.status == "TENTATIVE" and tr.mn_hits + (trk.confirm_N - tr.mn_scans) < trk.confirm_M:
            reason = "MN_failed"
        elif tr.misses >= trk.drop_K:
            reason = "K_misses"
        if reason is not None:
            self._drop(tr, reason, work, sid, t_ns, pred)

    def _drop(
        self, tr: TrackState, reason: str, work: _ScanWork, sid: int, t_ns: int, pred: TransformResult | None = None
    ) -> None:
        rep = self._track_reports([tr], sid, t_ns, work, [pred] if pred is not None else None)[0]
        rep = rep.model_copy(update={"status": "DROPPED", "drop_reason": reason, "confirm_progress": None})
        work.finals.append(rep)
        work.drops[reason] += 1
        self.metrics[f"dropped_{reason}"] += 1
        del self.tracks[tr.track_id]

    def _reset(self, work: _ScanWork, sid: int, t_ns: int) -> None:
        for tr in sorted(self.tracks.values(), key=lambda t: t.track_id):
            self._drop(tr, "reset", work, sid, t_ns)
        self.candidates = []

    def _initiate(
        self,
        p0: list[int],
        plots: NormalisedPlots,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
        sid: int,
        t_ns: int,
        work: _ScanWork,
    ) -> int:
        trk, lim = self.config.tracker, self.config.limits
        cands = [c for c in self.candidates if 1 <= sid - c.scan_id <= trk.init_L - 1 and c.t_ns < t_ns]
        cands.sort(key=lambda c: (c.scan_id, c.plot_id))
        paired_plots: set[int] = set()
        spawned: set[int] = set()
        new_pairs: list[tuple[int, int]] = []  # (candidate index, plot index)
        if cands and p0:
            k2 = np.array([conv_of[j] for j in p0])
            zc2, Rc2 = conv.y[k2], conv.R[k2]
            zc1 = np.stack([c.zc for c in cands])
            Rc1 = np.stack([c.Rc for c in cands])
            tau = np.array([(t_ns - c.t_ns) * 1e-9 for c in cands])
            passed, _, _ = ring_ellipse_test(
                zc1[:, None, :],
                Rc1[:, None, :, :],
                zc2[None, :, :],
                Rc2[None, :, :, :],
                tau[:, None],
                trk.ring_vmin_mps,
                trk.ring_vmax_mps,
                self.gamma3,
            )
            for ci, pj in zip(*np.nonzero(passed), strict=True):
                new_pairs.append((int(ci), int(pj)))
        n_created = 0
        if new_pairs:
            ci_arr = np.array([ci for ci, _ in new_pairs])
            pj_arr = np.array([p0[pj] for _, pj in new_pairs])
            z1 = np.stack([cands[ci].z for ci in ci_arr])
            s1 = np.stack([cands[ci].sig for ci in ci_arr])
            z2, s2 = plots.z[pj_arr], plots.sig[pj_arr]
            tau2 = np.array([(t_ns - cands[ci].t_ns) * 1e-9 for ci in ci_arr])
            if trk.scheme == "ukf_only":
                k2 = np.array([conv_of[j] for j in pj_arr])
                zc1 = np.stack([cands[ci].zc for ci in ci_arr])
                Rc1 = np.stack([cands[ci].Rc for ci in ci_arr])
                X, P = ukf_only_init(zc1, Rc1, conv.y[k2], conv.R[k2], tau2)
                phase = "ukf"
            else:
                xb, Pb = two_plot_bistatic_estimate(z1, s1, z2, s2, tau2, trk.init_cov)
                bkf_phase = trk.scheme == "bkf_only" or (trk.scheme == "bkf_ukf" and trk.confirm_M > 0)
                if bkf_phase:
                    X, P, phase = xb, Pb, "bkf"
                else:
                    res = bistatic_to_cartesian(xb, Pb, self.tx, trk.transform, work.chol)
                    X, P, phase = res.mean, res.cov, "ukf"
            status = "CONFIRMED" if trk.confirm_M == 0 else "TENTATIVE"
            n_conf = sum(1 for t in self.tracks.values() if t.status == "CONFIRMED")
            for k, (ci, pj) in enumerate(new_pairs):
                paired_plots.add(pj)
                spawned.add(ci)
                if status == "CONFIRMED" and n_conf >= lim.max_confirmed_tracks:
                    if "capacity" not in work.flags:
                        work.flags.append("capacity")
                    self.metrics["capacity_refused"] += 1
                    continue
                tid = self.next_track_id
                self.next_track_id += 1
                self.tracks[tid] = TrackState(
                    track_id=tid, status=status, phase=phase, x=X[k], P=P[k], t_ns=t_ns, created_scan=sid
                )
                n_conf += status == "CONFIRMED"
                work.created.add(tid)
                work.assoc[tid] = (plots.ids[p0[pj]], math.nan)
                n_created += 1
        spawned_ids = {id(cands[ci]) for ci in spawned}
        keep = [
            c
            for c in self.candidates
            if id(c) not in spawned_ids and sid - c.scan_id < trk.init_L - 1 and c.t_ns < t_ns
        ]
        for k, j in enumerate(p0):
            if k in paired_plots:
                continue
            kk = conv_of[j]
            keep.append(
                Candidate(
                    plot_id=plots.ids[j],
                    scan_id=sid,
                    t_ns=t_ns,
                    z=plots.z[j].copy(),
                    sig=plots.sig[j].copy(),
                    zc=conv.y[kk].copy(),
                    Rc=conv.R[kk].copy(),
                )
            )
        self.candidates = keep
        return n_created

    def _enforce_capacity(self, work: _ScanWork, sid: int, t_ns: int) -> None:
        lim = self.config.limits
        tent = [t for t in self.tracks.values() if t.status == "TENTATIVE"]
        excess = len(tent) - lim.max_tentative_tracks
        if excess <= 0:
            return
        tent.sort(key=lambda t: (t.hits, t.created_scan, t.track_id))
        for tr in tent[:excess]:
            self._drop(tr, "capacity", work, sid, t_ns)
        if "capacity" not in work.flags:
            work.flags.append("capacity")

    # ------------------------------------------------------------------------------------------ reports
    def _track_reports(
        self,
        trs: list[TrackState],
        sid: int,
        t_ns: int,
        work: _ScanWork,
        images: list[TransformResult | None] | None,
    ) -> list[PclTrackReport]:
        """Reports for tracks; ``images`` are reusable bistatic images (else computed by UT of x(k|k))."""
        if not trs:
            return []
        trk = self.config.tracker
        need = [k for k in range(len(trs)) if images is None or images[k] is None or trs[k].phase == "bkf"]
        imgs: list[TransformResult | None] = list(images) if images is not None else [None] * len(trs)
        cart: dict[int, tuple[FloatArray, FloatArray]] = {}
        for phase in ("ukf", "bkf"):
            idx = [k for k in need if trs[k].phase == phase]
            if not idx:
                continue
            X = np.stack([trs[k].x for k in idx])
            P = np.stack([trs[k].P for k in idx])
            if phase == "ukf":
                res = bistatic_image(X, P, self.tx, trk.transform, work.chol)
            else:
                res = bkf_measurement(X, P)
                ca = bistatic_to_cartesian(X, P, self.tx, trk.transform, work.chol)
                for m, k in enumerate(idx):
                    cart[k] = (ca.mean[m], ca.cov[m])
            for m, k in enumerate(idx):
                imgs[k] = TransformResult(res.mean[m : m + 1], res.cov[m : m + 1], res.cross[m : m + 1])
        out = []
        t_s = t_ns * 1e-9
        for k, tr in enumerate(trs):
            img = imgs[k]
            assert img is not None
            x, P = cart.get(k, (tr.x, tr.P))
            zb = img.mean[0] * _BISTATIC_UNITS
            Pb = symmetrize(img.cov[0] * np.outer(_BISTATIC_UNITS, _BISTATIC_UNITS))
            assoc = work.assoc.get(tr.track_id)
            nis = None if assoc is None or math.isnan(assoc[1]) else assoc[1]
            flags = list(work.track_flags.get(tr.track_id, []))
            if tr.track_id in work.created:
                flags.append("initiated")
            coasted = assoc is None
            if coasted:
                flags.append("coasted")
            out.append(
                PclTrackReport(
                    track_id=tr.track_id,
                    status=tr.status,  # type: ignore[arg-type]
                    scan_id=sid,
                    t_s=t_s,
                    state_enu=[float(v) for v in x],
                    cov_enu=symmetrize(P).tolist(),
                    bistatic=[float(v) for v in zb],
                    bistatic_cov=Pb.tolist(),
                    associated_plot_id=assoc[0] if assoc is not None else None,
                    nis=nis,
                    n_plots_in_gate=work.in_gate.get(tr.track_id, 0),
                    coasted=coasted,
                    updated=tr.track_id in work.updated,
                    hits=tr.hits,
                    consecutive_misses=tr.misses,
                    age_scans=max(sid - tr.created_scan, 0),
                    created_scan_id=tr.created_scan,
                    confirm_progress=[tr.mn_hits, tr.mn_scans] if tr.status == "TENTATIVE" else None,
                    filter_phase=tr.phase,  # type: ignore[arg-type]
                    flags=flags,
                )
            )
        return out

    def _scan_report(
        self, sid: int, t_ns: int, work: _ScanWork, plots: NormalisedPlots | None, trigger: str
    ) -> PclScanReport:
        live = sorted(self.tracks.values(), key=lambda t: t.track_id)
        images: list[TransformResult | None] = [work.images.get(t.track_id) for t in live]
        reports = self._track_reports(live, sid, t_ns, work, images) + work.finals
        reports.sort(key=lambda r: (r.track_id, r.status == "DROPPED"))
        nis = [v[1] for tid, v in work.assoc.items() if not math.isnan(v[1])]
        n_plots_in = 0 if plots is None else len(plots) + sum(plots.rejected.values())
        return PclScanReport(
            header=Header(stamp_ns=t_ns, frame_id=self.config.geometry.frame_id, source="pcl_tracker"),
            receiver_id=self.receiver_id,
            illuminator_id=self.illuminator_id,
            scan_id=sid,
            trigger=trigger,  # type: ignore[arg-type]
            t_s=t_ns * 1e-9,
            tracks=reports,
            n_plots_in=n_plots_in,
            n_plots_rejected=dict(plots.rejected) if plots is not None else {},
            n_plots_flagged=dict(plots.flagged) if plots is not None else {},
            n_candidates=len(self.candidates),
            n_tentative=sum(1 for t in live if t.status == "TENTATIVE"),
            n_confirmed=sum(1 for t in live if t.status == "CONFIRMED"),
            n_dropped=len(work.finals),
            n_coasting=sum(1 for t in live if t.track_id not in work.assoc),
            mean_nis=float(np.mean(nis)) if nis else None,
            gate_d2=self.gamma4,
            n_cholesky_fallbacks=work.chol.total,
            flags=list(dict.fromkeys(work.flags)),
        )

    # ------------------------------------------------------------------------------------------ snapshot
    def snapshot(self) -> dict[str, Any]:
        """Plain-data snapshot of the whole state (msgpack/JSON-able) for crash-restart (digest §5.4)."""

        def tr_dict(t: TrackState) -> dict[str, Any]:
            d = dict(t.__dict__)
            d["x"] = t.x.tolist()
            d["P"] = t.P.tolist()
            return d

        def c_dict(c: Candidate) -> dict[str, Any]:
            d = dict(c.__dict__)
            for k in ("z", "sig", "zc", "Rc"):
                d[k] = getattr(c, k).tolist()
            return d

        return {
            "config": self.config.model_dump(mode="json"),
            "tx": self.tx.tolist(),
            "wavelength_m": self.wavelength_m,
            "tracks": [tr_dict(t) for t in sorted(self.tracks.values(), key=lambda t: t.track_id)],
            "candidates": [c_dict(c) for c in self.candidates],
            "next_track_id": self.next_track_id,
            "last_scan_id": self.last_scan_id,
            "last_t_ns": self.last_t_ns,
            "buffer": [s.model_dump(mode="json") for _, s in sorted(self._buffer.items())],
            "skipped": sorted(self._skipped),
            "recent": [s.model_dump(mode="json") for _, s in sorted(self._recent.items())],
            "pending_flags": list(self._pending_flags),
            "counts_history": list(self._counts_history),
            "metrics": dict(self.metrics),
        }

    @classmethod
    def restore(cls, snap: dict[str, Any]) -> PclTracker:
        """Rebuild a tracker from :meth:`snapshot` output."""
        self = cls(PclTrackerConfig.model_validate(snap["config"]))
        self.tx = np.array(snap["tx"], dtype=np.float64)
        self.L_m = float(np.linalg.norm(self.tx))
        self.wavelength_m = snap["wavelength_m"]
        for d in snap["tracks"]:
            t = TrackState(**{**d, "x": np.array(d["x"]), "P": np.array(d["P"])})
            self.tracks[t.track_id] = t
        self.candidates = [
            Candidate(**{**d, **{k: np.array(d[k]) for k in ("z", "sig", "zc", "Rc")}}) for d in snap["candidates"]
        ]
        self.next_track_id = snap["next_track_id"]
        self.last_scan_id = snap["last_scan_id"]
        self.last_t_ns = snap["last_t_ns"]
        for s in snap["buffer"]:
            scan = BistaticScan.model_validate_json(_json_dumps(s))
            self._buffer[scan.scan_id] = scan
        self._skipped = set(snap["skipped"])
        for s in snap["recent"]:
            scan = BistaticScan.model_validate_json(_json_dumps(s))
            self._recent[scan.scan_id] = scan
        self._pending_flags = list(snap["pending_flags"])
        self._counts_history = list(snap["counts_history"])
        self.metrics = Counter(snap["metrics"])
        return self


def _json_dumps(obj: Any) -> str:
    import json

    return json.dumps(obj)
