"""Monte-Carlo runs of a scenario in-process (no Zenoh): simulators -> ordered events -> estimator cores -> metrics.

Run ``i`` of ``fixstream mc SCENARIO --runs N --seed S`` uses the seed sequence
``numpy.random.SeedSequence(S).spawn(N)[i]``, builds the scenario's simulators, takes the same ordered
event list the player would publish (:func:`services.player.timeline.stamp`), and computes

* ``sensor_stats`` (built in): per sensor key, the count and the error mean/SD/RMS of each component
  against truth (:mod:`services.player.sensor_stats`);
* per estimator named in the scenario, its plugin's mc module's ``run_core(events, params, scenario)``
  (:mod:`shared.plugins`).

Runs are spread over processes (``concurrent.futures.ProcessPoolExecutor``, spawn start method), or over the
workers of a Dask distributed cluster (``scheduler="tcp://HOST:PORT"``, the optional extra ``fixstream[dask]``;
see :func:`run_on_dask`), and collected by run index, so the JSON is identical for any number of workers and
either way. Aggregates: ``sensor_stats`` pooled over all samples of all runs, and each plugin's
``aggregate(per_run)``.

An mc module (``services/<kind>/mc.py`` by convention, named in the folder's ``plugin.py``) exposes::

    def run_core(events: list[Event], params: dict, scenario: Scenario) -> dict   # JSON-able metrics of one run
    def aggregate(per_run: list[dict]) -> dict                                    # over all runs
    Params: type[pydantic.BaseModel]                                              # optional, validates params
"""

from __future__ import annotations

import hashlib
import importlib
import json
import math
import multiprocessing
import os
import sys
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from types import ModuleType
from typing import Any

from services.player.scenario import Scenario
from services.player.sensor_stats import aggregate_sensor_stats, sensor_stats
from services.player.timeline import build, player_source, stamp
from shared.plugins import mc_module

#: the instance name in header.source of the events fed to the cores (``player/default``, as ``fixstream play``)
EVENT_INSTANCE = "default"


class MonteCarloError(RuntimeError):
    """The scenario cannot be run by ``fixstream mc`` (e.g. an estimator without an mc plugin)."""


class DaskUnavailable(MonteCarloError):
    """``scheduler`` was given but ``dask.distributed`` is not installed, or the scheduler cannot be reached."""


def load_plugin(kind: str) -> ModuleType:
    """The ``fixstream mc`` module of an estimator kind (its plugin's ``mc``), checked for ``run_core`` and
    ``aggregate``."""
    name = mc_module(kind)
    if name is None:
        raise MonteCarloError(f"estimator {kind!r} has no Monte-Carlo plugin (no plugin names an mc module for it)")
    module = importlib.import_module(name)
    for fn in ("run_core", "aggregate"):
        if not callable(getattr(module, fn, None)):
            raise MonteCarloError(f"{name} does not define {fn}()")
    return module


def jsonable(value: Any) -> Any:
    """Plain JSON types: numpy scalars and arrays become numbers and lists; NaN and inf become None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist"):  # numpy scalar or array
        return jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def run_once(scenario: Scenario, seed: int, run: int) -> dict[str, Any]:
    """Metrics of Monte-Carlo run ``run`` (pure: the same inputs give the same dict in any process)."""
    sim = build(scenario, seed, run)
    events = list(stamp(sim.raw_events(), player_source(EVENT_INSTANCE)))
    estimators: dict[str, Any] = {}
    for est in scenario.estimators:
        plugin = load_plugin(est.kind)
        estimators[est.instance] = plugin.run_core(events, dict(est.params), scenario)
    return jsonable(
        {
            "run": run,
            "events": len(events),
            "sensor_stats": sensor_stats(events, sim.context.platforms),
            "estimators": estimators,
        }
    )


def _task(args: tuple[Scenario, int, int]) -> dict[str, Any]:
    return run_once(*args)


def run_montecarlo(
    scenario: Scenario,
    runs: int,
    seed: int | None = None,
    workers: int | None = None,
    progress: bool = True,
    scheduler: str | None = None,
) -> dict[str, Any]:
    """All runs, per-run and aggregate metrics as a JSON-able dict. ``scheduler``: the address of a Dask
    distributed scheduler whose workers run the runs (``workers`` is then not used)."""
    from tqdm import tqdm

    if runs < 1:
        raise MonteCarloError("runs must be >= 1")
    seed = scenario.seed if seed is None else seed
    plugins = {est.instance: load_plugin(est.kind) for est in scenario.estimators}
    workers = max(1, min(workers or os.cpu_count() or 1, runs))
    results: list[dict[str, Any] | None] = [None] * runs
    on_dask = run_on_dask(scheduler, scenario, seed, runs) if scheduler is not None else None
    with tqdm(total=runs, desc=f"mc {scenario.name}", unit="run", file=sys.stderr, disable=not progress) as bar:
        if on_dask is not None:
            for i, result in on_dask:
                results[i] = result
                bar.update()
        elif workers == 1:
            for i in range(runs):
                results[i] = run_once(scenario, seed, i)
                bar.update()
        else:
            ctx = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                futures = {pool.submit(_task, (scenario, seed, i)): i for i in range(runs)}
                for fut in as_completed(futures):
                    results[futures[fut]] = fut.result()
                    bar.update()
    per_run = [r for r in results if r is not None]
    aggregate = {
        "sensor_stats": aggregate_sensor_stats([r["sensor_stats"] for r in per_run]),
        "estimators": {
            instance: plugin.aggregate([r["estimators"][instance] for r in per_run])
            for instance, plugin in plugins.items()
        },
    }
    return jsonable(
        {
            "scenario": scenario.name,
            "seed": seed,
            "runs": runs,
            "estimators": [{"kind": e.kind, "instance": e.instance} for e in scenario.estimators],
            "per_run": per_run,
            "aggregate": aggregate,
        }
    )


def run_on_dask(scheduler: str, scenario: Scenario, seed: int, runs: int) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(run index, run_once(scenario, seed, run))`` for every run, as the Dask cluster at ``scheduler`` finishes them
    (connected and submitted on the call, collected as the iterator is read).

    Each run is one task (``run_once``, pure), submitted with the scenario pickled; the workers need the same
    fixstream (and its scenario files, maps and tracks at the same relative paths, in their working directory) as
    this process. A run that raises on a worker raises here. The cluster is Dask's own: scheduling, retries on a
    lost worker and its dashboard are Dask's, nothing is brokered here."""
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise DaskUnavailable(NO_DASK) from None
    check_scheduler_address(scheduler)
    try:
        client = Client(scheduler, timeout=DASK_CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise DaskUnavailable(f"no Dask scheduler reachable at {scheduler}: {exc}") from None
    # task keys name the campaign (scenario, seed, runs) and the run: distinct campaigns never share a result
    token = hashlib.blake2b(f"{scenario.model_dump_json()}|{seed}|{runs}".encode(), digest_size=8).hexdigest()
    futures = {
        client.submit(run_once, scenario, seed, i, key=f"fixstream-mc-{scenario.name}-{token}-{i}", pure=False): i
        for i in range(runs)
    }

    def results() -> Iterator[tuple[int, dict[str, Any]]]:
        try:
            for fut in dask_completed(futures, loop=client.loop):
                yield futures[fut], fut.result()
        finally:
            client.close()

    return results()


def check_scheduler_address(scheduler: str) -> None:
    """:class:`DaskUnavailable` unless ``scheduler`` is an address Dask can parse (``tcp://HOST:PORT``, ``HOST:PORT``,
    another of its protocols), checked before a ``Client`` is built: a client that fails to parse its address is
    left half-built, and its finaliser then waits the connect timeout (40 s) before a traceback."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler)
        if scheme in ("tcp", "tls"):
            host, port = parse_host_port(location)
            if not host or not 0 < port < 65536:
                raise ValueError(f"{scheduler!r} needs a host and a port 1-65535")
    except ValueError as exc:
        raise DaskUnavailable(f"no Dask scheduler reachable at {scheduler}: {exc} (expected tcp://HOST:PORT)") from None


def dask_available() -> bool:
    """Whether ``dask.distributed`` can be imported (the optional extra ``fixstream[dask]``)."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        return False
    return True


NO_DASK = "--scheduler needs dask.distributed, which is not installed: pip install 'fixstream[dask]'"
#: how long the Dask client tries to reach its scheduler, s
DASK_CONNECT_TIMEOUT_S = 20.0


def dumps(result: dict[str, Any]) -> str:
    """Canonical JSON text (sorted keys, no NaN), so equal results give equal files."""
    return json.dumps(result, indent=2, sort_keys=True, allow_nan=False) + "\n"


def write(result: dict[str, Any], path: str | Path) -> None:
    p = Path(path)
    if p.parent and not p.parent.exists():
        p.parent.mkdir(parents=True)
    p.write_text(dumps(result))
