"""AUV-group navigation with docked AUVs as range-difference LBL beacons (digest 002): the pure core.

``core.RdNavCore`` (one per moving AUV) turns acoustic arrivals and DR sensors into ``RdNavFix`` and
``TdoaCycle`` messages; ``simulation`` and ``inprocess`` reproduce the digest's REF/LOW experiments;
``metrics`` computes their statistics. The coordinator core is in ``services.coordinator``.
"""
