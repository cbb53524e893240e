"""The PCL tracker core: one instance = one receiver–illuminator pair (digest 003 §5).

``PclTracker.step(msg)`` takes a :class:`~schemas.radar.BistaticScan` or a
:class:`~schemas.radar.BistaticConfigUpdate` and returns the :class:`~schemas.pcl_tracker.PclScanReport`
messages it produced (usually one; zero while a scan waits in the reorder buffer; several when the buffer
is released). Inputs it refuses raise :class:`shared.service.InputRejected`; the state stays valid.
There is no I/O and no wall clock: time is ``header.stamp_ns`` of the scan.

The tracker is built from declared components (Stone Soup style), each a constructor argument with a
default made from the configuration, and each with its maths in its module doc:

* :class:`~.frontend.FrontEnd`: stream hygiene (pair, geometry updates, reorder buffer, duplicates, gaps,
  plot checks, clutter bursts);
* ``predictor`` (:mod:`.predictor`), ``associator`` (:mod:`.associator`), ``updater`` (:mod:`.updater`),
  ``initiator`` (:mod:`.initiator`), ``confirmer`` and ``deleter`` (:mod:`.deleter`);
* :class:`~.reports.ReportBuilder` (:mod:`.reports`): the output messages.

:meth:`PclTracker._track` is the per-scan loop of §5.5 that composes them.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from typing import Any, cast

import numpy as np

from schemas.pcl_tracker import PclScanReport, PclTrackReport
from schemas.radar import BistaticConfigUpdate, BistaticScan
from shared.errors import InputRejected

from .associator import Association, Associator, GatedAssociator
from .config import PclTrackerConfig
from .deleter import MissDeleter, MofNConfirmer
from .filter import ConvertedPlots, convert_plots
from .frontend import FrontEnd, ScanInput
from .geometry import BoolArray, FloatArray
from .initiator import Initiator, TwoPlotInitiator
from .models import plot_covariance
from .plots import NormalisedPlots
from .predictor import BistaticPredictor, Prediction, Predictor
from .reports import ReportBuilder
from .state import CandidateSet, ScanWork, TrackState
from .updater import PclUpdater, Updater

__all__ = ["CandidateSet", "PclTracker", "ScanWork", "TrackState"]


class PclTracker:
    """Passive coherent locator tracker: bistatic association, Cartesian UKF, 2/L initiation, M/N confirmation.

    Every component can be replaced by passing another one that has the same interface (module doc).
    """

    def __init__(
        self,
        config: PclTrackerConfig | None = None,
        *,
        predictor: Predictor | None = None,
        associator: Associator | None = None,
        updater: Updater | None = None,
        initiator: Initiator | None = None,
        confirmer: MofNConfirmer | None = None,
        deleter: MissDeleter | None = None,
    ) -> None:
        cfg = config or PclTrackerConfig()
        #: running metrics (digest §5.7)
        self.metrics: Counter[str] = Counter()
        self.front = FrontEnd(cfg, self.metrics)
        self._given: dict[str, Any] = {
            k: v
            for k, v in (
                ("predictor", predictor),
                ("associator", associator),
                ("updater", updater),
                ("initiator", initiator),
                ("confirmer", confirmer),
                ("deleter", deleter),
            )
            if v is not None
        }
        self.config = cfg
        self.tracks: dict[int, TrackState] = {}
        self.candidates = CandidateSet.empty()
        self.next_track_id = 1

    @property
    def config(self) -> PclTrackerConfig:
        return self._config

    @config.setter
    def config(self, cfg: PclTrackerConfig) -> None:
        """A new configuration: the front end and every component not given to the constructor follow it."""
        self._config = cfg
        trk, lim = cfg.tracker, cfg.limits
        self.gamma4 = trk.gamma4
        self.gamma3 = trk.gamma3
        self.front.config = cfg
        given = self._given
        self.predictor = cast(Predictor, given.get("predictor") or BistaticPredictor(trk))
        self.associator = cast(Associator, given.get("associator") or GatedAssociator(trk))
        self.updater = cast(Updater, given.get("updater") or PclUpdater(trk))
        self.initiator = cast(Initiator, given.get("initiator") or TwoPlotInitiator(trk, lim))
        self.confirmer = cast(MofNConfirmer, given.get("confirmer") or MofNConfirmer(trk))
        self.deleter = cast(MissDeleter, given.get("deleter") or MissDeleter(trk, lim))
        self.reports = ReportBuilder(cfg)

    # ------------------------------------------------------------------------------------------ the loop
    def _track(self, s: ScanInput) -> PclScanReport:
        """One scan (digest §5.5): gap, plots, predict, associate, update, confirm/delete, initiate, report."""
        work = ScanWork(flags=s.flags)
        self._gap(s, work)  # 0. coast the missing scans, or reset after a long gap
        plots, burst = self.front.check_plots(s.scan, work.flags)  # 0. validate / normalise plots
        R_plot = plot_covariance(plots.sig)
        live = sorted(self.tracks.values(), key=lambda t: (t.status != "CONFIRMED", t.track_id))
        tau = np.array([(s.t_ns - tr.t_ns) * 1e-9 for tr in live])
        pred = self.predictor.predict(live, tau, self.tx, work.chol)  # 1. predict, inverse UT to bistatic
        for tr in live:
            tr.t_ns = s.t_ns
        work.pred, work.model_images = pred.images, pred.model_images
        assoc = self.associator.associate(live, pred, plots.z, R_plot)  # 2.-3. gate, assign
        pool, strongest = self.initiator.pool(plots, assoc.in_some_gate, burst)
        conv, conv_of = self._convert(plots, assoc, pool, strongest, work)  # UT n = 3 of the plots needed
        self._update(live, pred, assoc, plots, R_plot, conv, conv_of, work)  # 4. update, M/N, K misses
        n_init = self._initiate(plots, conv, conv_of, pool, burst, strongest, s, work)  # 5. initiation
        self._enforce_capacity(work)
        self.front.scan_done(len(plots))
        return self._report(s, plots, work, len(assoc.pairs), n_init, int(conv.clamped.sum()))  # 6.

    # ------------------------------------------------------------------------------------------ public API
    def step(self, msg: BistaticScan | BistaticConfigUpdate) -> list[PclScanReport]:
        """Process one input message; return the scan reports it produced."""
        if isinstance(msg, BistaticConfigUpdate):
            return self._on_config(msg)
        if isinstance(msg, BistaticScan):
            self.front.admit(msg)
            return [self._track(s) for s in self.front.ready()]
        raise InputRejected("wrong_type", f"unsupported input {type(msg).__name__}")

    def flush(self) -> list[PclScanReport]:
        """Process every buffered scan in scan_id order (end of stream)."""
        return [self._track(s) for s in self.front.flush()]

    @property
    def buffered_scan_ids(self) -> list[int]:
        """Scans waiting in the reorder buffer (processed when their predecessor arrives, or by flush)."""
        return self.front.buffered_scan_ids

    def predict(self, track_id: int, stamp_ns: int) -> PclTrackReport:
        """[D] On-demand extrapolation of a live track to ``stamp_ns`` (no state change)."""
        tr = self.tracks.get(track_id)
        if tr is None:
            raise KeyError(track_id)
        tau = np.array([(stamp_ns - tr.t_ns) * 1e-9])
        ghost = TrackState(**{**tr.__dict__, "x": tr.x.copy(), "P": tr.P.copy()})  # the predictor rebinds arrays
        self.predictor.predict([ghost], tau, self.tx)  # (an IMM track's output is the mixture)
        ghost.t_ns = stamp_ns
        scan_id = self.last_scan_id if self.last_scan_id is not None else 0
        return self.reports.track_reports([ghost], scan_id, stamp_ns, ScanWork(), None, self.tx)[0]

    def successor(self) -> PclTracker:
        """A fresh tracker for the next run: same configuration and components, track ids continuing."""
        nxt = PclTracker(self.config, **self._given)
        nxt.next_track_id = self.next_track_id
        return nxt

    def status(self) -> dict[str, Any]:
        """The core's figures for a status report: counts of scans, tracks, candidates and the §5.7 metrics."""
        return {
            "scans_processed": self.metrics["scans"],
            "buffered_scans": len(self.front.buffer),
            "last_scan_id": self.last_scan_id,
            "live_tracks": len(self.tracks),
            "tentative": sum(1 for t in self.tracks.values() if t.status == "TENTATIVE"),
            "confirmed": sum(1 for t in self.tracks.values() if t.status == "CONFIRMED"),
            "candidates": len(self.candidates),
            "next_track_id": self.next_track_id,
            "core_metrics": dict(self.metrics),
        }

    # the front end's view of the stream, as attributes of the tracker
    @property
    def receiver_id(self) -> str:
        return self.front.receiver_id

    @property
    def illuminator_id(self) -> str:
        return self.front.illuminator_id

    @property
    def tx(self) -> FloatArray:
        return self.front.tx

    @property
    def L_m(self) -> float:
        return self.front.L_m

    @property
    def wavelength_m(self) -> float | None:
        return self.front.wavelength_m

    @property
    def last_scan_id(self) -> int | None:
        return self.front.last_scan_id

    @property
    def last_t_ns(self) -> int | None:
        return self.front.last_t_ns

    # ------------------------------------------------------------------------------------------ loop steps
    def _on_config(self, msg: BistaticConfigUpdate) -> list[PclScanReport]:
        if not self.front.configure(msg):
            return []
        work = ScanWork(flags=["config_reset"])
        stamp = msg.header.stamp_ns
        scan_id = self.last_scan_id if self.last_scan_id is not None else 0
        self._reset(work)
        self.metrics["config_resets"] += 1
        return [self._scan_report(scan_id, stamp, work, None, trigger="config")]

    def _gap(self, s: ScanInput, work: ScanWork) -> None:
        """§5.5 step 0: after ``gap`` missing scans every track records ``gap`` misses; a long gap resets."""
        if s.reset:
            self._reset(work)
            self.metrics["gap_resets"] += 1
        elif s.gap > 0:
            for tr in sorted(self.tracks.values(), key=lambda t: t.track_id):
                self.confirmer.miss(tr, s.gap)
                self._maybe_drop(tr, work)

    def _convert(
        self, plots: NormalisedPlots, assoc: Association, pool: BoolArray, strongest: bool, work: ScanWork
    ) -> tuple[ConvertedPlots, dict[int, int]]:
        """UT (n = 3) of the plots an update or the initiation needs, once per plot; row of each plot."""
        need = np.zeros(len(plots), dtype=bool)
        for _, c in assoc.pairs:
            need[c] = True
        need |= pool if strongest else ~assoc.in_some_gate
        need &= ~plots.low_rb
        conv_idx = np.flatnonzero(need)
        trk = self.config.tracker
        conv = convert_plots(plots.z[conv_idx, :3], plots.sig[conv_idx, :3], self.tx, trk.transform, work.chol)
        return conv, {int(j): k for k, j in enumerate(conv_idx)}

    def _update(
        self,
        live: list[TrackState],
        pred: Prediction,
        assoc: Association,
        plots: NormalisedPlots,
        R_plot: FloatArray,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
        work: ScanWork,
    ) -> None:
        """§5.5 step 4: update the assigned tracks, count hits (M/N) and misses (K), drop what fails."""
        for i, tr in enumerate(live):
            work.in_gate[tr.track_id] = int(assoc.n_in_gate[i])
        assigned = dict(assoc.pairs)
        for i, c in assigned.items():
            work.assoc[live[i].track_id] = (plots.ids[c], assoc.d2[(i, c)])
        updated, skipped = self.updater.update(live, pred, assigned, plots, R_plot, conv, conv_of)
        for i, flag in skipped.items():
            work.track_flags.setdefault(live[i].track_id, []).append(flag)
        work.updated.update(live[i].track_id for i in updated)
        for i in sorted(assigned):
            self.confirmer.hit(live[i], self.tx, work.chol)
        for i, tr in enumerate(live):
            if i in assigned:
                continue
            self.confirmer.miss(tr)
            self._maybe_drop(tr, work, pred=i)
        for i, tr in enumerate(live):
            if tr.track_id not in work.updated:
                work.images[tr.track_id] = i  # x(k|k) = x(k|k-1): reuse the inverse UT

    def _initiate(
        self,
        plots: NormalisedPlots,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
        pool: BoolArray,
        burst: bool,
        strongest: bool,
        s: ScanInput,
        work: ScanWork,
    ) -> int:
        """§5.5 step 5: new tracks from P0 and the candidates (none in a suppressed burst); their ids."""
        if strongest:
            work.flags.append("burst_snr_initiation")
        if burst and not strongest:
            self.candidates = self.initiator.expire(self.candidates, s.scan_id)
            return 0
        p0 = [j for j in np.flatnonzero(pool).tolist() if j in conv_of and bool(conv.valid[conv_of[j]])]
        new = self.initiator.initiate(p0, plots, conv, conv_of, self.candidates, s.scan_id, s.t_ns, self.tx, work.chol)
        n_conf = sum(1 for t in self.tracks.values() if t.status == "CONFIRMED")
        n_created = 0
        for tr, j in zip(new.tracks, new.plot_rows, strict=True):
            if tr.status == "CONFIRMED" and n_conf >= self.config.limits.max_confirmed_tracks:
                if "capacity" not in work.flags:
                    work.flags.append("capacity")
                self.metrics["capacity_refused"] += 1
                continue
            tr.track_id = self.next_track_id
            self.next_track_id += 1
            self.tracks[tr.track_id] = tr
            n_conf += tr.status == "CONFIRMED"
            work.created.add(tr.track_id)
            work.assoc[tr.track_id] = (plots.ids[j], math.nan)
            n_created += 1
        self.candidates = new.candidates
        return n_created

    def _report(
        self, s: ScanInput, plots: NormalisedPlots, work: ScanWork, n_assoc: int, n_init: int, n_clamped: int
    ) -> PclScanReport:
        """§5.5 step 6: the scan's report, and the running metrics."""
        n_in = len(s.scan.plots)
        extra = {
            "n_associated": n_assoc,
            "n_initiated": n_init,
            "gap_scans": max(s.gap, 0),
            "n_sigma_clamped": n_clamped,
            "n_plots_in": n_in,
        }
        report = self._scan_report(s.scan_id, s.t_ns, work, plots, trigger="scan", extra=extra)
        self.metrics["scans"] += 1
        self.metrics["plots_in"] += n_in
        self.metrics["associated"] += n_assoc
        self.metrics["initiated"] += n_init
        self.metrics["cholesky_fallbacks"] += work.chol.total
        for k, v in plots.rejected.items():
            self.metrics[f"rejected_{k}"] += v
        return report

    def _scan_report(
        self,
        sid: int,
        t_ns: int,
        work: ScanWork,
        plots: NormalisedPlots | None,
        trigger: str,
        extra: dict[str, Any] | None = None,
    ) -> PclScanReport:
        live = sorted(self.tracks.values(), key=lambda t: t.track_id)
        return self.reports.scan_report(live, len(self.candidates), sid, t_ns, work, plots, self.tx, trigger, extra)

    # ------------------------------------------------------------------------------------------ drops
    def _maybe_drop(self, tr: TrackState, work: ScanWork, pred: int | None = None) -> None:
        if self.confirmer.failed(tr):
            self._drop(tr, "MN_failed", work, pred)
        elif self.deleter.deletes(tr):
            self._drop(tr, "K_misses", work, pred)

    def _drop(self, tr: TrackState, reason: str, work: ScanWork, pred: int | None = None) -> None:
        """Remove a track; its final report is built with the scan's other reports (batched)."""
        work.dropping.append((tr, reason, pred))
        work.drops[reason] += 1
        self.metrics[f"dropped_{reason}"] += 1
        del self.tracks[tr.track_id]

    def _enforce_capacity(self, work: ScanWork) -> None:
        victims = self.deleter.over_capacity(list(self.tracks.values()))
        for tr in victims:
            self._drop(tr, "capacity", work)
        if victims and "capacity" not in work.flags:
            work.flags.append("capacity")

    def _reset(self, work: ScanWork) -> None:
        for tr in sorted(self.tracks.values(), key=lambda t: t.track_id):
            self._drop(tr, "reset", work)
        self.candidates = CandidateSet.empty()

    # ------------------------------------------------------------------------------------------ snapshot
    def snapshot(self) -> dict[str, Any]:
        """Plain-data snapshot of the whole state (msgpack/JSON-able) for crash-restart (digest §5.4)."""
        f = self.front
        return {
            "config": self.config.model_dump(mode="json"),
            "tx": f.tx.tolist(),
            "wavelength_m": f.wavelength_m,
            "tracks": [t.to_dict() for t in sorted(self.tracks.values(), key=lambda t: t.track_id)],
            "candidates": self.candidates.to_list(),
            "next_track_id": self.next_track_id,
            "last_scan_id": f.last_scan_id,
            "last_t_ns": f.last_t_ns,
            "buffer": [s.model_dump(mode="json") for _, s in sorted(f.buffer.items())],
            "skipped": sorted(f.skipped),
            "recent": [s.model_dump(mode="json") for _, s in sorted(f.recent.items())],
            "pending_flags": list(f.pending_flags),
            "counts_history": list(f.counts_history),
            "metrics": dict(self.metrics),
        }

    @classmethod
    def restore(cls, snap: dict[str, Any], **components: Any) -> PclTracker:
        """Rebuild a tracker from :meth:`snapshot` output (with the default components, or those given)."""
        self = cls(PclTrackerConfig.model_validate(snap["config"]), **components)
        f = self.front
        f.tx = np.array(snap["tx"], dtype=np.float64)
        f.L_m = float(np.linalg.norm(f.tx))
        f.wavelength_m = snap["wavelength_m"]
        for d in snap["tracks"]:
            t = TrackState.from_dict(d)
            self.tracks[t.track_id] = t
        self.candidates = CandidateSet.from_list(snap["candidates"])
        self.next_track_id = snap["next_track_id"]
        f.last_scan_id = snap["last_scan_id"]
        f.last_t_ns = snap["last_t_ns"]
        for s in snap["buffer"]:
            scan = BistaticScan.model_validate_json(json.dumps(s))
            f.buffer[scan.scan_id] = scan
        f.skipped = set(snap["skipped"])
        for s in snap["recent"]:
            scan = BistaticScan.model_validate_json(json.dumps(s))
            f.recent[scan.scan_id] = scan
        f.pending_flags = list(snap["pending_flags"])
        f.counts_history = list(snap["counts_history"])
        self.metrics.update(snap["metrics"])
        return self
