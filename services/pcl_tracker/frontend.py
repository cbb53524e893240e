"""The tracker's front end: stream hygiene before the tracking loop (digest 003 §5.5 step 0, §5.6).

It owns what the stream, not the targets, decides:

* the pair and the geometry: inputs of another receiver–illuminator pair are refused (``wrong_pair``); a
  :class:`~schemas.radar.BistaticConfigUpdate` changes the wavelength, and a moved transmitter (baseline L)
  means the tracker must reset (:meth:`FrontEnd.configure`);
* ordering: a scan at or before the last processed one is refused as ``duplicate_scan`` (same scan id seen,
  content compared without the publisher's seq/source) or ``late_scan_dropped``; a stamp that does not
  increase is refused (``time_not_monotonic``); a scan ahead of its predecessor waits in the reorder buffer
  until the predecessor arrives, or the buffer holds more than ``reorder_window_scans`` scans (then the
  missing scans count as a gap), or :meth:`FrontEnd.flush`;
* gaps: gap = scan_id - last_scan_id - 1 missing scans; beyond ``max_gap_scans`` the tracker resets
  (``gap_reset``), else every live track counts ``gap`` misses first (``gap_coast``);
* plot checks: :func:`.plots.normalise_plots` (refused plots by reason, kept-but-unusual ones flagged), and
  the clutter-burst test: more than ``max_plots_per_scan`` valid plots, or more than ``burst_factor`` times
  the median count of the last ``burst_history_scans`` scans (at least ``burst_min_plots``).

A released scan comes out as a :class:`ScanInput` with the scan flags raised so far.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.radar import BistaticConfigUpdate, BistaticScan
from shared.errors import InputRejected

from .config import PclTrackerConfig
from .plots import NormalisedPlots, normalise_plots

#: scans kept to recognise duplicates, behind the last processed one
_RECENT_SCANS = 16


@dataclass
class ScanInput:
    """A scan released to the tracking loop, in order."""

    scan: BistaticScan
    #: scan flags so far (pending ones from dropped inputs, then the gap's)
    flags: list[str]
    #: missing scans since the last processed one (0 for the first scan)
    gap: int
    #: the gap is too long: drop every track (else the tracks coast ``gap`` scans)
    reset: bool

    @property
    def scan_id(self) -> int:
        return self.scan.scan_id

    @property
    def t_ns(self) -> int:
        return self.scan.header.stamp_ns


class FrontEnd:
    """Pair, geometry, ordering, gaps and plot checks of one tracker (module doc); counts into ``metrics``."""

    def __init__(self, config: PclTrackerConfig, metrics: Counter[str]) -> None:
        self.config = config
        geo = config.geometry
        self.receiver_id = geo.receiver_id
        self.illuminator_id = geo.illuminator_id
        self.tx = np.array(geo.tx_position_enu_m, dtype=np.float64)
        self.L_m = float(np.linalg.norm(self.tx))
        self.wavelength_m = geo.wavelength_m
        self.metrics = metrics
        self.last_scan_id: int | None = None
        self.last_t_ns: int | None = None
        self.buffer: dict[int, BistaticScan] = {}
        self.skipped: set[int] = set()
        self.recent: dict[int, BistaticScan] = {}
        self.pending_flags: list[str] = []
        self.counts_history: list[int] = []

    # ------------------------------------------------------------------------------------------ pair, geometry
    def check_pair(self, receiver_id: str, illuminator_id: str) -> None:
        if receiver_id != self.receiver_id or illuminator_id != self.illuminator_id:
            raise InputRejected(
                "wrong_pair",
                f"{receiver_id}/{illuminator_id} is not this tracker's pair {self.receiver_id}/{self.illuminator_id}",
            )

    def configure(self, msg: BistaticConfigUpdate) -> bool:
        """Apply a configuration update; True if the transmitter moved (the tracker must reset)."""
        self.check_pair(msg.receiver_id, msg.illuminator_id)
        tx = np.array(msg.tx_position_enu_m, dtype=np.float64)
        if not np.all(np.isfinite(tx)):
            raise InputRejected("nan", "non-finite transmitter position")
        if msg.wavelength_m is not None:
            self.wavelength_m = msg.wavelength_m
        if np.array_equal(tx, self.tx):
            return False
        self.tx = tx
        self.L_m = float(np.linalg.norm(tx))
        return True

    # ------------------------------------------------------------------------------------------ ordering
    @staticmethod
    def _content(scan: BistaticScan) -> dict[str, Any]:
        """What makes two copies of a scan the same (publisher seq/source excluded)."""
        return scan.model_dump(exclude={"header": {"seq", "source"}})

    def admit(self, scan: BistaticScan) -> None:
        """Refuse a scan of another pair, a duplicate, a late scan or one back in time; else buffer it."""
        self.check_pair(scan.receiver_id, scan.illuminator_id)
        sid = scan.scan_id
        last = self.last_scan_id
        if (last is not None and sid <= last) or sid in self.buffer:
            known = self.recent.get(sid) or self.buffer.get(sid)
            if known is not None:
                same = self._content(known) == self._content(scan)
                self.metrics["duplicate_scans"] += 1
                raise InputRejected(
                    "duplicate_scan", f"scan {sid} already seen ({'same' if same else 'different'} content)"
                )
            self.pending_flags.append("late_scan_dropped")
            self.metrics["late_scans"] += 1
            raise InputRejected("late_scan_dropped", f"scan {sid} arrived after scan {last} was processed")
        ref_t = self.last_t_ns
        if ref_t is not None and scan.header.stamp_ns <= ref_t:
            self.skipped.add(sid)
            self.metrics["time_not_monotonic"] += 1
            raise InputRejected("time_not_monotonic", f"scan {sid} stamp {scan.header.stamp_ns} <= {ref_t}")
        self.buffer[sid] = scan

    def ready(self) -> Iterator[ScanInput]:
        """The buffered scans that can go now, in order (each released when the loop asks for the next)."""
        window = self.config.limits.reorder_window_scans
        while self.buffer:
            first = min(self.buffer)
            last = self.last_scan_id
            nxt = (last + 1) if last is not None else first
            # scan ids between the last released and the first buffered that may still come: counted, not listed
            # (a jump of 1e8 in scan_id, which the schema allows, once built a list of 3.8 GB)
            missing = first - nxt - sum(1 for s in self.skipped if nxt <= s < first)
            if first == nxt or missing <= 0 or len(self.buffer) > window:
                yield from self._release(self.buffer.pop(first))
            else:
                break

    def flush(self) -> Iterator[ScanInput]:
        """Every buffered scan in scan_id order (end of stream)."""
        for sid in sorted(self.buffer):
            yield from self._release(self.buffer.pop(sid))

    @property
    def buffered_scan_ids(self) -> list[int]:
        return sorted(self.buffer)

    def _release(self, scan: BistaticScan) -> Iterator[ScanInput]:
        if self.last_t_ns is not None and scan.header.stamp_ns <= self.last_t_ns:
            # a buffered scan that turned out older than what was processed: drop it, flag the next report
            self.skipped.add(scan.scan_id)
            self.pending_flags.append("time_not_monotonic")
            self.metrics["time_not_monotonic"] += 1
            return
        sid = scan.scan_id
        flags = list(dict.fromkeys(self.pending_flags))
        self.pending_flags.clear()
        gap = 0 if self.last_scan_id is None else sid - self.last_scan_id - 1
        reset = gap > self.config.limits.max_gap_scans
        if reset:
            flags.append("gap_reset")
        elif gap > 0:
            flags.append("gap_coast")
        self.last_scan_id = sid
        self.last_t_ns = scan.header.stamp_ns
        self.recent[sid] = scan
        for old in [s for s in self.recent if s < sid - _RECENT_SCANS]:
            del self.recent[old]
        self.skipped = {s for s in self.skipped if s > sid}
        yield ScanInput(scan, flags, gap, reset)

    # ------------------------------------------------------------------------------------------ plots
    def check_plots(self, scan: BistaticScan, flags: list[str]) -> tuple[NormalisedPlots, bool]:
        """The scan's usable plots, and whether the scan is a clutter burst; appends the scan flags."""
        plots = normalise_plots(scan.plots, self.config, self.L_m, self.wavelength_m)
        for k in plots.flagged:
            if k in ("sigma_defaulted", "near_baseline"):
                flags.append(k)
        burst = self._burst(len(plots))
        if burst:
            flags.append("clutter_burst")
            self.metrics["clutter_bursts"] += 1
        return plots, burst

    def _burst(self, n: int) -> bool:
        lim = self.config.limits
        if n > lim.max_plots_per_scan:
            return True
        hist = self.counts_history[-lim.burst_history_scans :]
        if len(hist) < lim.burst_history_scans or n < lim.burst_min_plots:
            return False
        return n > lim.burst_factor * max(float(np.median(hist)), 1.0)

    def scan_done(self, n_valid: int) -> None:
        """A scan with ``n_valid`` usable plots went through: it enters the burst test's history."""
        lim = self.config.limits
        self.counts_history.append(n_valid)
        del self.counts_history[: -lim.burst_history_scans]
