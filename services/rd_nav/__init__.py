"""AUV-group navigation with docked AUVs as range-difference LBL beacons (digest 002).

``core.RdNavCore`` (one per moving AUV) turns acoustic arrivals and DR sensors into ``RdNavFix`` and
``TdoaCycle`` messages; ``service`` is its Zenoh adapter (``fixstream run rd_nav``); ``simulation`` and
``offline`` reproduce the digest's REF/LOW experiments; ``simulator`` is the player plugin ``rd_group`` (the
group in a closed loop with the coordinator); ``metrics`` and ``mc`` compute their statistics. The coordinator
(core, protocol, service, mc plugin) is in ``services.coordinator``. See ``docs/rd_nav.md``.
"""
