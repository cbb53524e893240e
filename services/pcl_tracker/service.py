"""The PCL tracker service: one instance per receiver–illuminator pair (digest 003 §5), a thin adapter.

decode → validate → :class:`~services.pcl_tracker.core.PclTracker` → encode. Keys (``<rx>``/``<tx>`` are
the configured ``receiver_id`` / ``illuminator_id``):

* in: ``fixstream/sensor/<rx>/pcl/<tx>``, :class:`~schemas.radar.BistaticScan` (one per scan, empty scans too)
  and :class:`~schemas.radar.BistaticConfigUpdate` (same key, so geometry changes keep their order);
* out: ``fixstream/track/pcl/<rx>/<tx>``, one :class:`~schemas.pcl_tracker.PclScanReport` per processed scan;
* ``fixstream/scenario/**``: the player's markers (the service base ends the run once every scan the end
  marker announces for our key has arrived);
* ``fixstream/diag/pcl_tracker/<instance>``, ``fixstream/status/pcl_tracker/<instance>`` and the liveliness
  token ``fixstream/alive/pcl_tracker/<instance>`` (service base).

Bad input (digest §5.6, architecture rule 5) never stops the service and never reaches the estimate:

* a message that cannot be decoded, has the wrong type or pair, is a duplicate, late, or goes back in time
  is rejected as a whole (the base counts it and publishes a diagnostic with the core's reason);
* a scan whose *plots* fail validation (NaN/inf, elevation beyond ±90°, not exactly one range and one
  velocity form) keeps its valid plots: the bad ones are dropped and reported (reason ``nan``,
  ``out_of_range``, ``missing_quantity``, ``invalid_plot``) exactly like the plots the core refuses
  (``rb_below_baseline``, ``duplicate_plot_id``, ``no_wavelength``, ...), and the report counts them in
  ``n_plots_in`` / ``n_plots_rejected``;
* plots kept but unusual (``low_rb``, ``near_baseline``, ``sigma_defaulted``) and scan conditions
  (``clutter_burst``, whose detail says whether initiation kept the strongest plots by SNR, ``gap_coast``,
  ``gap_reset``, ``capacity``, ``config_reset``, ``time_not_monotonic`` of a buffered scan, ``out_of_order``
  of a scan buffered for reordering, ``conversion_failed``, ``cholesky_fallback``) are reported as diagnostics
  too, level ``info`` or ``warning``.

Deterministic: outputs depend only on the order of the inputs on the input key (time comes from the
stamps). The end of a player run flushes the reorder buffer and then starts a fresh tracker for the next
run (track ids keep increasing, so an id is never reused within an instance). The end marker can overtake
the last scans (another subscription); the ``Service`` base waits for the scans it announces (or
``end_wait_s`` of quiet, or the next start marker) before calling :meth:`PclTrackerService.on_scenario_end`.
"""

from __future__ import annotations

import gc
import json
import logging
import os
import time
from collections import Counter
from typing import Any, ClassVar, Literal

from schemas import Message, ScenarioMarker
from schemas.pcl_tracker import PclScanReport
from schemas.radar import BistaticConfigUpdate, BistaticScan
from shared import codec, keys
from shared.service import Output, Service, Subscription
from shared.settings import ZenohSettings

from .core import PclTracker
from .plots import salvage_plots
from .settings import PclTrackerSettings, PclTrackerSettingsBase, to_config

log = logging.getLogger("fixstream.pcl_tracker")

#: what the tracker reads on its pair's key
INPUTS: tuple[type[Message], ...] = (BistaticScan, BistaticConfigUpdate)
#: plot-level reasons (count per plot): a plot refused or flagged inside an accepted scan
_PLOT_FLAGS_INFO = {"low_rb", "near_baseline", "sigma_defaulted"}
#: scan flags already reported another way (a rejected message, or a plot flag)
_FLAGS_REPORTED_ELSEWHERE = {"late_scan_dropped", "sigma_defaulted", "near_baseline", "burst_snr_initiation"}
_FLAGS_INFO = {"gap_coast"}


def input_key(receiver_id: str, illuminator_id: str) -> str:
    return keys.sensor(receiver_id, "pcl", illuminator_id)


def output_key(receiver_id: str, illuminator_id: str) -> str:
    return keys.track("pcl", receiver_id, illuminator_id)


class PclTrackerService(Service):
    """Runs one :class:`PclTracker` (one receiver–illuminator pair) on the stream; see the module doc."""

    name: ClassVar[str] = "pcl_tracker"

    def __init__(self, settings: PclTrackerSettingsBase, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = to_config(settings)
        self.snapshot_file = settings.snapshot_file
        self.snapshot_every = settings.snapshot_every_scans
        geo = self.config.geometry
        self.in_key = input_key(geo.receiver_id, geo.illuminator_id)
        self.out_key = output_key(geo.receiver_id, geo.illuminator_id)
        self.core = self._restore() or PclTracker(self.config)
        #: plots received in accepted messages (including the ones dropped at decoding)
        self.plots_received = 0
        #: plots refused, by reason (decoding and core)
        self.plots_rejected: Counter[str] = Counter()
        #: every scan-level diagnostic reason (plot rejections, plot flags, scan flags), running counts
        self.scan_events: Counter[str] = Counter()
        self.reports_published = 0
        self.scans_since_snapshot = 0
        self.last_scan_ms: float | None = None
        self.max_scan_ms = 0.0
        #: wall time of the core per input scan (a health figure, never used in estimation)
        self.total_scan_ms = 0.0
        self.total_scan_cpu_ms = 0.0
        self.timed_scans = 0
        self.resets = 0
        #: plots refused at decoding, per scan id, until that scan's report is published
        self._dropped_by_scan: dict[int, Counter[str]] = {}
        #: plots :meth:`_salvage` refused in the sample being dispatched (read, and cleared, by its handler)
        self._salvaged: Counter[str] = Counter()

    # ----- Service hooks ------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.in_key, self._on_input, accepts=INPUTS, salvage=self._salvage)]

    def flush_run(self, marker: ScenarioMarker) -> list[Output]:
        """Every scan of the run has arrived (the base waits for them): flush the reorder buffer."""
        return self._outputs(self.in_key, self.core.flush())

    def new_run(self, reason: str) -> list[Output]:
        """A fresh tracker for the next run (track ids keep increasing)."""
        self.core = self.core.successor()
        self._dropped_by_scan.clear()
        self.resets += 1
        return list(super().new_run(reason))

    def on_stop(self) -> None:
        self._save_snapshot()

    def status_extra(self) -> dict[str, Any]:
        core = self.core.status()
        metrics = core.pop("core_metrics")
        return {
            "pair": {"receiver_id": self.core.receiver_id, "illuminator_id": self.core.illuminator_id},
            "in_key": self.in_key,
            "out_key": self.out_key,
            "scans_processed": core.pop("scans_processed"),
            "reports_published": self.reports_published,
            **core,
            "plots_received": self.plots_received,
            "plots_rejected": sum(self.plots_rejected.values()),
            "plots_rejected_by_reason": dict(self.plots_rejected),
            "scan_events": dict(self.scan_events),
            "core_metrics": metrics,
            "last_scan_ms": self.last_scan_ms,
            "max_scan_ms": round(self.max_scan_ms, 3),
            "mean_scan_ms": round(self.total_scan_ms / self.timed_scans, 3) if self.timed_scans else None,
            "mean_scan_cpu_ms": round(self.total_scan_cpu_ms / self.timed_scans, 3) if self.timed_scans else None,
            "tracker_resets": self.resets,
        }

    # ----- sample path --------------------------------------------------------------------------
    def _on_input(self, key: str, msg: Message) -> list[Output]:
        """One validated scan or configuration update (the base decoded it once, :meth:`_salvage` repairing a scan
        with bad plots): run the core, count the plots refused at decoding in the scan's report."""
        assert isinstance(msg, BistaticScan | BistaticConfigUpdate)
        dropped, self._salvaged = self._salvaged, Counter()
        scan = msg if isinstance(msg, BistaticScan) else None
        last = self.core.last_scan_id
        t0, c0 = time.perf_counter(), time.thread_time()
        reports = self.core.step(msg)  # InputRejected: the whole message is refused (the base reports it)
        if scan is not None:
            self.plots_received += len(scan.plots) + sum(dropped.values())
            if dropped:
                self._dropped_by_scan[scan.scan_id] = dropped
            ms = (time.perf_counter() - t0) * 1e3
            self.last_scan_ms = round(ms, 3)
            self.max_scan_ms = max(self.max_scan_ms, ms)
            self.total_scan_ms += ms
            self.total_scan_cpu_ms += (time.thread_time() - c0) * 1e3
            self.timed_scans += 1
            if last is not None and scan.scan_id > last + 1 and scan.scan_id in self.core.buffered_scan_ids:
                detail = f"scan {scan.scan_id} arrived after {last}: held for reordering (or counted as a gap)"
                self._event(key, "out_of_order", detail, scan.header.stamp_ns, "info")
        return self._outputs(key, reports)

    def _salvage(self, model: type[Message], obj: Any, error: codec.DecodeError) -> Message:
        """A scan whose only problems are in some plots loses those plots, not the scan (they are counted in its
        report); anything else re-raises the decoding error."""
        plots = obj.get("plots") if isinstance(obj, dict) else None
        if model is not BistaticScan or not isinstance(plots, list):
            raise error
        good, dropped = salvage_plots(plots)
        if not dropped and good == plots:
            raise error
        scan = codec.validate(BistaticScan, {**obj, "plots": good})
        self._salvaged = dropped
        return scan

    def _outputs(self, key: str, reports: list[PclScanReport]) -> list[Output]:
        outputs: list[Output] = []
        for rep in reports:
            dropped = self._dropped_by_scan.pop(rep.scan_id, None) if rep.trigger == "scan" else None
            if dropped:  # plots refused at decoding count in their scan's report like the core's rejections
                rejected = Counter(rep.n_plots_rejected)
                rejected.update(dropped)
                rep = rep.model_copy(
                    update={"n_plots_in": rep.n_plots_in + sum(dropped.values()), "n_plots_rejected": dict(rejected)}
                )
            self._diagnose(key, rep)
            outputs.append(Output(self.out_key, rep))
        last = self.core.last_scan_id
        if last is not None and self._dropped_by_scan:  # buffered scans the core dropped after all
            for sid in [s for s in self._dropped_by_scan if s <= last]:
                for reason, n in self._dropped_by_scan.pop(sid).items():
                    self._plot_rejections(key, reason, n, sid, 0)
        self.reports_published += len(outputs)
        if outputs and self.snapshot_every:
            self.scans_since_snapshot += len(outputs)
            if self.scans_since_snapshot >= self.snapshot_every:
                self._save_snapshot()
        return outputs

    # ----- diagnostics --------------------------------------------------------------------------
    def _event(
        self, key: str, reason: str, detail: str, stamp_ns: int, level: Literal["info", "warning"], n: int = 1
    ) -> None:
        self.count_event(self.scan_events, key, reason, detail, n=n, level=level, stamp_ns=stamp_ns)

    def _plot_rejections(self, key: str, reason: str, n: int, scan_id: int, stamp_ns: int) -> None:
        self.plots_rejected[reason] += n
        self._event(key, reason, f"scan {scan_id}: {n} plot(s) rejected", stamp_ns, "warning", n)

    def _diagnose(self, key: str, rep: PclScanReport) -> None:
        stamp = rep.header.stamp_ns
        sid = rep.scan_id
        for reason, n in rep.n_plots_rejected.items():
            self._plot_rejections(key, reason, n, sid, stamp)
        for flag, n in rep.n_plots_flagged.items():
            level: Literal["info", "warning"] = "info" if flag in _PLOT_FLAGS_INFO else "warning"
            self._event(key, flag, f"scan {sid}: {n} plot(s) {flag}", stamp, level, n)
        for flag in rep.flags:
            if flag in _FLAGS_REPORTED_ELSEWHERE:
                continue
            detail = f"scan {sid}: {flag}"
            if flag == "gap_coast":
                detail += f" ({rep.gap_scans} missing scan(s) counted as misses)"
            elif flag == "clutter_burst" and "burst_snr_initiation" in rep.flags:
                detail += f" ({rep.n_plots_in} plots: initiation from the strongest plots by SNR only)"
            elif flag == "clutter_burst":
                detail += f" ({rep.n_plots_in} plots: association only, no initiation)"
            self._event(key, flag, detail, stamp, "info" if flag in _FLAGS_INFO else "warning")
        failed = [t.track_id for t in rep.tracks if "conversion_failed" in t.flags]
        if failed:
            self._event(key, "conversion_failed", f"scan {sid}: tracks {failed} not updated", stamp, "warning")
        if rep.n_cholesky_fallbacks:
            self._event(key, "cholesky_fallback", f"scan {sid}: {rep.n_cholesky_fallbacks}", stamp, "info")

    # ----- snapshot -----------------------------------------------------------------------------
    def _restore(self) -> PclTracker | None:
        path = self.snapshot_file
        if path is None or not path.exists():
            return None
        try:
            snap = json.loads(path.read_text())
            core = PclTracker.restore(snap)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("%s: snapshot %s not usable (%s): starting fresh", self.source, path, exc)
            return None
        if core.config != self.config:
            log.warning("%s: snapshot %s has another configuration: starting fresh", self.source, path)
            return None
        log.info(
            "%s: restored %d tracks from %s (last scan %s)", self.source, len(core.tracks), path, core.last_scan_id
        )
        return core

    def _save_snapshot(self) -> None:
        self.scans_since_snapshot = 0
        path = self.snapshot_file
        if path is None:
            return
        tmp = path.with_name(path.name + ".tmp")
        try:
            tmp.write_text(json.dumps(self.core.snapshot(), allow_nan=False))
            os.replace(tmp, path)
        except (OSError, ValueError) as exc:
            log.error("%s: could not write the snapshot %s: %s", self.source, path, exc)


def from_environment() -> PclTrackerService:
    """The service configured from ``FIXSTREAM_PCL_TRACKER_*`` (and the optional config file)."""
    settings = PclTrackerSettings.load()
    assert isinstance(settings, PclTrackerSettingsBase)
    return PclTrackerService(settings)


def build() -> PclTrackerService:
    """The service as ``fixstream run pcl_tracker`` starts it (:func:`from_environment`)."""
    service = from_environment()
    # Everything allocated so far lives for the whole process: keep the cyclic collector from re-scanning it
    # at every full collection (one scan of many plots allocates enough to trigger several).
    gc.collect()
    gc.freeze()
    return service
