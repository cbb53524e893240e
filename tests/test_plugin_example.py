"""Adding an estimator takes its folder and one entry-point line (issue 19 item 2), shown with a small one.

``depth_mean`` lives in a temporary directory, outside the repository: a package with a pure core, a service, a
simulator kind and an mc module, and a ``dist-info`` whose ``entry_points.txt`` holds the one line
``depth_mean = depth_mean.plugin:PLUGIN`` (what ``pyproject.toml`` gives the repository's estimators). With that
directory on PYTHONPATH and nothing else changed: ``fixstream run depth_mean`` serves over a real router,
``fixstream scenarios validate`` knows its simulator kind, ``fixstream mc`` computes its metrics, the recorder's
Foxglove channels draw its fixes (its ``views.py``) and ``fixstream report`` gives it a section (its
``report.py``, ranked and titled by its plugin).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
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
    "depth_mean/views.py": """
        import numpy as np

        from shared.foxglove.frames import Estimate


        def depth_fix(key, msg, ctx):
            if not key.startswith("fixstream/fix/depth_mean/"):
                return []  # the sensor's depths are not estimates
            instance = key.rsplit("/", 1)[1]
            pos = np.array([0.0, 0.0, -msg.depth_m])
            return [Estimate("fix", instance, instance, msg.header.stamp_ns, pos, label=f"mean {msg.depth_m:.2f} m")]
        """,
    "depth_mean/report.py": """
        from schemas import Depth
        from tools.report.plots.common import Section, new_figure, render


        def build(data, metrics):
            out = []
            for src in data.sources("depth_mean"):
                means = [ev.msg for ev in data.outputs[src] if isinstance(ev.msg, Depth)]
                sec = Section("depth_mean", src.split("/", 1)[1], f"Depth mean — {src.split('/', 1)[1]}")
                fig, axs = new_figure()
                axs[0][0].plot([m.header.stamp_ns / 1e9 for m in means], [m.depth_m for m in means])
                sec.figures.append(render(fig, "running mean of the depth", "m against s"))
                sec.headline = {"messages": len(means), "last_mean_m": means[-1].depth_m if means else None}
                out.append(sec)
            return out
        """,
    "depth_mean/plugin.py": """
        from shared.plugins import Plugin, ReportSection

        PLUGIN = Plugin(
            name="depth_mean",
            service="depth_mean.service:build",
            simulators={"depth_mean_sim": "depth_mean.simulator"},
            mc={"depth_mean": "depth_mean.mc"},
            summary="the mean depth so far: the smallest estimator there is",
            views={"Depth": "depth_mean.views:depth_fix"},
            report=ReportSection("depth_mean.report", rank=5, title="Running depth mean"),
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


#: records the example's run offline with the recorder's Foxglove channels, then reports on it
RECORD_AND_REPORT = """
import json, sys
from pathlib import Path

from services.player.scenario import load_scenario
from shared.foxglove.convert import Converter
from shared.foxglove.recording import FoxgloveChannels
from tools.registry import load_service
from tools.report import make_report
from tools.report.offline import scenario_feed, write_recording

scenario_path, out = sys.argv[1], Path(sys.argv[2])
scenario = load_scenario(scenario_path)
feed = scenario_feed(scenario)
sensor = [(k, m) for k, m in feed if k.startswith("fixstream/sensor/dm1/") or k.startswith("fixstream/scenario/")]
outputs = [(o.key, o.msg) for o in load_service("depth_mean").run_offline(sensor)]
foxglove = FoxgloveChannels(Converter.for_scenario(scenario))
(file,) = write_recording(out / "rec", feed, outputs, prefix="dm", foxglove=foxglove)
make_report([file], out / "report", scenario=scenario_path, progress=False, workers=1)
depths = [m.depth_m for k, m in feed if k == "fixstream/sensor/dm1/depth/d0"]
(out / "run.json").write_text(json.dumps({"file": str(file), "depths": depths}))
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


def test_the_example_gets_foxglove_views_and_a_report_section(example: dict[str, str], tmp_path: Path) -> None:
    from test_foxglove import foxglove_records

    script = tmp_path / "record_and_report.py"
    script.write_text(RECORD_AND_REPORT)
    out = tmp_path / "out"
    env = {**example, "FIXSTREAM_INSTANCE": "dm1"}
    done = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "depth_mean_demo.yaml"), str(out)],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    run = json.loads((out / "run.json").read_text())
    depths = run["depths"]
    assert len(depths) >= 19  # 20 s at 1 Hz
    mean = sum(depths) / len(depths)  # what the last running mean must be, computed here
    # Foxglove: one scene update per published mean, an entity at depth = the mean; nothing for the sensor key
    scene = [(topic, msg) for topic, _, _, msg in foxglove_records(Path(run["file"])) if "depth" in topic]
    assert {topic for topic, _ in scene} == {"/foxglove/scene/fix/depth_mean/dm1"}
    assert len(scene) == len(depths)
    (entity,) = scene[-1][1].entities
    assert entity.id == "dm1"
    assert entity.spheres[0].pose.position.z == pytest.approx(-mean, rel=1e-12)
    # the report: the example's own section, placed by its rank, headline from its module, its title in the summary
    metrics = json.loads((out / "report" / "metrics.json").read_text())
    (section,) = [s for s in metrics["sections"] if s["kind"] == "depth_mean"]
    assert section["instance"] == "dm1"
    assert section["headline"]["messages"] == len(depths)
    assert section["headline"]["last_mean_m"] == pytest.approx(mean, rel=1e-12)
    page = (out / "report" / "index.html").read_text()
    assert "Depth mean — dm1" in page and "Running depth mean" in page
    assert "running mean of the depth" in page  # its figure
