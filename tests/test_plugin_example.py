"""Adding an estimator takes its folder and one entry-point line (issue 19 item 2), shown with a small one.

``depth_mean`` lives in a temporary directory, outside the repository: a package with a pure core, a service, a
simulator kind and an mc module, and a ``dist-info`` whose ``entry_points.txt`` holds the one line
``depth_mean = depth_mean.plugin:PLUGIN`` (what ``pyproject.toml`` gives the repository's estimators). With that
directory on PYTHONPATH and nothing else changed: ``fixstream run depth_mean`` serves over a real router,
``fixstream scenarios validate`` knows its simulator kind and ``fixstream mc`` computes its metrics.
"""

from __future__ import annotations

import json
import os
import subprocess
import textwrap
from pathlib import Path

import pytest
import zenoh
from conftest import REPO, fixstream_cmd, wait_until

from schemas import Depth, Header
from shared import codec
from shared.session import open_session, query_all
from shared.settings import ZenohSettings

pytestmark = pytest.mark.e2e

FILES = {
    "depth_mean/__init__.py": "",
    "depth_mean/core.py": '''
        """The mean of the depths seen so far (the whole estimator)."""


        class DepthMean:
            def __init__(self) -> None:
                self.n, self.total = 0, 0.0

            def step(self, depth_m: float) -> float:
                self.n += 1
                self.total += depth_m
                return self.total / self.n
        ''',
    "depth_mean/service.py": """
        from schemas import Depth, Header
        from shared.service import Output, Service, Subscription
        from shared.settings import ServiceSettings

        from .core import DepthMean


        class DepthMeanService(Service):
            name = "depth_mean"

            def __init__(self, settings):
                super().__init__(settings)
                self.core = DepthMean()

            def subscriptions(self):
                return [Subscription(f"fixstream/sensor/{self.instance}/depth/*", self.on_depth, accepts=(Depth,))]

            def on_depth(self, key, msg):
                mean = self.core.step(msg.depth_m)
                return [Output(f"fixstream/fix/depth_mean/{self.instance}", Depth(header=msg.header, depth_m=mean))]


        def build():
            return DepthMeanService(ServiceSettings.load())
        """,
    "depth_mean/simulator.py": """
        import numpy as np

        from schemas import Depth
        from services.player.simulators import Event, SimParams, register
        from services.player.simulators.base import sample_stamps_ns


        class Params(SimParams):
            platform: str = "dm1"
            depth_m: float = 50.0
            sigma_m: float = 0.5


        @register("depth_mean_sim")
        class DepthMeanSim:
            Params = Params

            def __init__(self, params, rng, context):
                self.p, self.rng, self.ctx = params, rng, context

            def events(self):
                for t in sample_stamps_ns(1.0, self.ctx.duration_ns):
                    z = self.p.depth_m + self.p.sigma_m * self.rng.standard_normal()
                    key = f"fixstream/sensor/{self.p.platform}/depth/d0"
                    yield Event(int(t), key, Depth(header=self.ctx.header(int(t)), depth_m=float(z)))
        """,
    "depth_mean/mc.py": """
        from .core import DepthMean


        def run_core(events, params, scenario):
            core = DepthMean()
            means = [core.step(ev.msg.depth_m) for ev in events if ev.key.endswith("/depth/d0")]
            return {"n": len(means), "last_mean_m": means[-1] if means else None}


        def aggregate(per_run):
            return {"runs": len(per_run), "n": sum(r["n"] for r in per_run)}
        """,
    "depth_mean/plugin.py": """
        from shared.plugins import Plugin

        PLUGIN = Plugin(
            name="depth_mean",
            service="depth_mean.service:build",
            simulators={"depth_mean_sim": "depth_mean.simulator"},
            mc={"depth_mean": "depth_mean.mc"},
            summary="the mean depth so far: the smallest estimator there is",
        )
        """,
    "depth_mean-0.1.dist-info/METADATA": "Metadata-Version: 2.1\nName: depth_mean\nVersion: 0.1\n",
    "depth_mean-0.1.dist-info/entry_points.txt": "[fixstream.plugins]\ndepth_mean = depth_mean.plugin:PLUGIN\n",
}

SCENARIO = """
format: 1
name: depth_mean_demo
seed: 3
duration_s: 20
frame_id: local_enu
simulators:
  - kind: depth_mean_sim
    id: dm
    params: {platform: dm1, depth_m: 50.0, sigma_m: 0.5}
estimators:
  - {kind: depth_mean, instance: dm1}
"""


@pytest.fixture()
def example(tmp_path: Path) -> dict[str, str]:
    site = tmp_path / "site"
    for name, text in FILES.items():
        path = site / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text).lstrip())
    (tmp_path / "depth_mean_demo.yaml").write_text(SCENARIO)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(REPO), env.get("PYTHONPATH", "")])
    return env


def test_an_estimator_from_its_folder_and_one_entry_point_line(example: dict[str, str], tmp_path: Path) -> None:
    scenario = tmp_path / "depth_mean_demo.yaml"
    done = subprocess.run(
        fixstream_cmd("scenarios", "validate", str(scenario)), env=example, cwd=tmp_path, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout + done.stderr
    out = tmp_path / "mc.json"
    done = subprocess.run(
        fixstream_cmd("mc", str(scenario), "--runs", "2", "--seed", "1", "--out", str(out), "--workers", "1"),
        env=example,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    metrics = json.loads(out.read_text())
    text = json.dumps(metrics)
    assert '"last_mean_m"' in text and '"runs": 2' in text  # the example's own run_core and aggregate ran


def test_the_example_service_runs_over_a_real_router(example: dict[str, str], router: str) -> None:
    env = {**example, "FIXSTREAM_ZENOH_MODE": "client", "FIXSTREAM_ZENOH_CONNECT": router, "FIXSTREAM_INSTANCE": "dm1"}
    proc = subprocess.Popen(fixstream_cmd("run", "depth_mean"), env=env, cwd=REPO, text=True)
    client = open_session(ZenohSettings(mode="client", connect=[router]))
    got: list[float] = []
    sub = client.declare_subscriber(
        "fixstream/fix/depth_mean/dm1",
        lambda s: got.append(codec.decode(s.payload.to_bytes(), str(s.encoding)).depth_m),
    )
    try:
        assert wait_until(lambda: len(list(client.liveliness().get("fixstream/alive/depth_mean/dm1", timeout=0.5))), 60)
        enc = zenoh.Encoding(codec.encoding_of(Depth))
        for i, d in enumerate([10.0, 20.0, 60.0]):
            payload = codec.encode_stamped(Depth(header=Header(stamp_ns=i), depth_m=d), "player/x", i)
            client.put("fixstream/sensor/dm1/depth/d0", payload, encoding=enc)
        assert wait_until(lambda: len(got) == 3, timeout=30)
        assert got == [10.0, 15.0, 30.0]  # the running means, computed by hand
        (reply,) = query_all(client, "fixstream/status/depth_mean/dm1", 5.0)
        assert reply.ok is not None and json.loads(reply.ok.payload.to_bytes())["counters"]["accepted"] == 3
    finally:
        sub.undeclare()
        client.close()
        proc.terminate()
        assert proc.wait(timeout=30) == 0
