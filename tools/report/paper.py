"""The papers' own figures, from the digests in ``../shared/seeds/`` (what each paper reports, for the summary).

Each entry: (what the paper measured, its figure, where in the digest). The report puts them beside the
headline metrics of one run; they are Monte-Carlo or field figures, so a single run is a sanity check, not a
reproduction (``fixstream mc`` does the statistics).
"""

from __future__ import annotations

PAPER: dict[str, list[tuple[str, str, str]]] = {
    "terrain_nav": [
        ("correction error, modified algorithm", "≤ 1 cell (≤ 125 m) on both axes", "digest 001 §3.2, Fig. 2"),
        ("correction error, base algorithm", "24 cells transverse, 1 cell longitudinal", "digest 001 §3.2"),
    ],
    "lbl_nav": [
        ("false hypothesis chosen", "never, in 1500 runs", "digest 000 §3.1"),
        ("resolution after launch (field data)", "4 s with buffered data, 16 s without", "digest 000 §0, §3.2"),
        ("computed vs actual RMS", "close, with and without buffered data (0–20 m axis)", "digest 000 §3.1"),
    ],
    "rd_nav": [
        ("PF error, per coordinate (4 h, 100 runs)", "mean ≤ 0.25 m, SD ≤ 0.75 m, max ≤ 2 m", "digest 002 §5.1"),
        ("dead reckoning alone after 4 h", "≈ 150 m", "digest 002 §5.1"),
    ],
    "pcl_tracker": [
        ("steady-state 3-D position RMSE (1000 runs)", "< 50 m", "digest 003 §0, §3.3"),
        ("steady-state velocity RMSE", "1–2 m/s", "digest 003 §3.3"),
    ],
    "attitude": [
        ("LOS-angle accuracy", "units of degrees after ~40 contacts (≈ 200 s at T = 5 s)", "digest 004 §3.5"),
        ("first contacts", "low accuracy (Kalman-filter transients)", "digest 004 §3.5"),
    ],
}

__all__ = ["PAPER"]
