"""The Monte-Carlo metrics of a recording: each estimator's ``fixstream mc`` plugin on what it published.

For every estimator the scenario names (``estimators: [{kind, instance, params}]``), the plugin
``services/<kind>/mc.py`` exposes ``run_metrics(outputs, events, params, scenario)``: a pure function of what
the estimator published and the scenario's events. ``fixstream mc`` calls it on the outputs of the core run
in-process (``run_core``); the report calls it on the outputs the recording holds — the messages whose
``header.source`` is ``<kind>/<instance>`` — and the events the player published. The same run therefore gives
the same figures both ways, except the keys a plugin lists in ``OFFLINE_ONLY`` (the core's internal counters,
which nothing published carries; the report shows the service's diagnostics counts instead).

A plugin without ``run_metrics`` (an estimator whose mc plugin predates the split, or has none) is listed with
the reason; its plots are drawn all the same.
"""

from __future__ import annotations

import importlib
import traceback
from typing import Any

from shared.plugins import mc_module
from tools.montecarlo import jsonable

from .data import RunData


def plugin_metrics(data: RunData) -> dict[str, dict[str, Any]]:
    """Per estimator instance of the scenario: kind, source, status and the plugin's metrics (or why not)."""
    out: dict[str, dict[str, Any]] = {}
    sc = data.scenario
    if sc is None:
        return out
    for est in sc.estimators:
        source = f"{est.kind}/{est.instance}"
        entry: dict[str, Any] = {"kind": est.kind, "source": source, "metrics": None}
        out[est.instance] = entry
        module = mc_module(est.kind)
        if module is None:
            entry["status"] = f"no Monte-Carlo plugin for {est.kind} (no plugin names an mc module)"
            continue
        plugin = importlib.import_module(module)
        run_metrics = getattr(plugin, "run_metrics", None)
        if not callable(run_metrics):
            entry["status"] = f"{module} has no run_metrics()"
            continue
        outputs = data.outputs.get(source, [])
        if not outputs:
            entry["status"] = f"no output of {source} in the recording"
            continue
        try:
            entry["metrics"] = jsonable(run_metrics(outputs, data.events, dict(est.params), sc))
            entry["status"] = "ok"
            entry["offline_only"] = list(getattr(plugin, "OFFLINE_ONLY", ()))
        except Exception as exc:  # a plugin bug must not lose the rest of the report
            entry["status"] = f"run_metrics failed: {type(exc).__name__}: {exc}"
            entry["traceback"] = traceback.format_exc(limit=5)
    return out


__all__ = ["plugin_metrics"]
