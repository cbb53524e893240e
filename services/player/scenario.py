"""The scenario file: a strict pydantic model of the public YAML format (documented in docs/scenarios.md).

Loading validates everything, including each simulator's ``params`` against that simulator's own model,
and reports every problem as ``<file>: <field path>: <message>``, e.g.
``scenarios/x.yaml: simulators[0].params.sensors[1].dvl.sigma_mps: Input should be greater than or equal to 0``.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)

from shared import keys, yaml_numbers
from shared.foxglove.frames import frame_axes
from shared.plugins import mc_module, plugins

from .simulators import NS_PER_S, SimParams, UnknownSimulator, get_simulator

DEFAULT_DIR_ENV = "FIXSTREAM_SCENARIOS_DIR"
SUFFIXES = (".yaml", ".yml")


class ScenarioError(ValueError):
    """A scenario file that cannot be read or does not validate; the message names the file and fields."""


def _chunk(v: str) -> str:
    return keys.chunk(v)


KeyChunk = Annotated[str, AfterValidator(_chunk)]


def wait_name(v: str) -> str:
    parts = v.split("/")
    if len(parts) not in (1, 2):
        raise ValueError(f"expected 'service' or 'service/instance', got {v!r}")
    for p in parts:
        keys.chunk(p)
    return v


def _package_name(v: str) -> str:
    if not v.isidentifier():
        raise ValueError(f"{v!r} is not a package name under services/")
    return v


class _Strict(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True, allow_inf_nan=False)


class SimulatorSpec(_Strict):
    """One simulator: its registered kind, a unique id and its own parameters."""

    kind: str = Field(min_length=1, max_length=64, description="registered simulator kind, e.g. nav_platform")
    id: KeyChunk = Field(description="unique within the scenario; also names its random stream")
    params: dict[str, Any] = Field(default_factory=dict, description="validated by the simulator's Params model")

    _params: SimParams | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _check_params(self) -> SimulatorSpec:
        try:
            cls = get_simulator(self.kind)
        except UnknownSimulator as exc:
            raise ValueError(f".kind: {exc}") from None
        try:
            self._params = cls.Params.model_validate(self.params, strict=True)
        except ValidationError as exc:
            raise ValueError("\n".join(f".params{_path(e['loc'])}: {_msg(e)}" for e in exc.errors())) from None
        return self

    @property
    def validated_params(self) -> SimParams:
        """The params as the simulator's own model (defaults filled in)."""
        assert self._params is not None
        return self._params


class EstimatorSpec(_Strict):
    """An estimator the scenario is meant for (used by ``fixstream mc`` and end-to-end comparisons)."""

    kind: Annotated[str, AfterValidator(_package_name)] = Field(description="a services/<kind> package")
    instance: KeyChunk = Field(default="default", description="instance name, unique within the scenario")
    params: dict[str, Any] = Field(default_factory=dict, description="passed to the estimator's mc plugin")

    @model_validator(mode="after")
    def _check_kind(self) -> EstimatorSpec:
        problems = _check_estimator(self)
        if problems:
            raise ValueError("\n".join(problems))
        return self


class GeodeticOrigin(_Strict):
    """The geodetic point at the origin of the scenario frame (ENU axes there): maps and Foxglove's LocationFix."""

    lat_deg: float = Field(ge=-90.0, le=90.0, description="latitude, deg (WGS84)")
    lon_deg: float = Field(ge=-180.0, le=180.0, description="longitude, deg (WGS84)")
    alt_m: float = Field(default=0.0, ge=-11_000.0, le=100_000.0, description="height above the ellipsoid, m")


class Scenario(_Strict):
    """A scenario file."""

    format: Literal[1] = Field(default=1, description="version of the scenario file format")
    name: KeyChunk = Field(description="scenario name; markers go to fixstream/scenario/<name>")
    description: str = Field(default="", max_length=10_000)
    seed: int = Field(default=0, ge=0, lt=2**63, description="default seed (fixstream play --seed overrides)")
    duration_s: float = Field(gt=0.0, le=1e7, description="simulated duration, s")
    frame_id: str = Field(default="local_enu", min_length=1, max_length=128, description="header.frame_id")
    origin: GeodeticOrigin | None = Field(default=None, description="where [0, 0, 0] of frame_id is on the Earth")
    wait_for: list[Annotated[str, AfterValidator(wait_name)]] = Field(
        default_factory=list, description="'service' (any instance) or 'service/instance' that must be alive"
    )
    wait_timeout_s: float = Field(default=30.0, gt=0.0, le=86_400.0, description="s")
    simulators: list[SimulatorSpec] = Field(min_length=1, max_length=1000)
    estimators: list[EstimatorSpec] = Field(default_factory=list, max_length=1000)

    @field_validator("frame_id")
    @classmethod
    def _enu_frame(cls, value: str) -> str:
        conv = frame_axes(value)
        if conv != "enu":  # the truth is east, north, up: a frame read with other axes would swap it in every view
            raise ValueError(
                f"{value!r} names a frame whose axes are not east, north, up ({conv}; docs/report.md, 'One frame for"
                " everything'), while the scenario's truth is: name it e.g. 'local_enu' or 'map_enu'"
            )
        return value

    @model_validator(mode="after")
    def _unique(self) -> Scenario:
        problems: list[str] = []
        ids = [s.id for s in self.simulators]
        for i, sid in enumerate(ids):
            if sid in ids[:i]:
                problems.append(f"simulators[{i}].id: duplicate simulator id {sid!r}")
        instances = [e.instance for e in self.estimators]
        for i, inst in enumerate(instances):
            if inst in instances[:i]:
                problems.append(f"estimators[{i}].instance: duplicate estimator instance {inst!r}")
        if problems:
            raise ValueError("\n".join(problems))
        return self

    @property
    def duration_ns(self) -> int:
        return round(self.duration_s * NS_PER_S)

    def simulator_params(self, index: int) -> SimParams:
        """The validated parameters of ``simulators[index]`` (the simulator's own Params model)."""
        return self.simulators[index].validated_params

    def wait_keys(self) -> list[str]:
        """Liveliness key expressions that must all match a live token before the player starts."""
        return wait_keys(self.wait_for)


def wait_keys(names: list[str]) -> list[str]:
    """'service' (any instance) or 'service/instance' -> liveliness key expressions."""
    out = []
    for name in names:
        service, _, instance = wait_name(name).partition("/")
        out.append(keys.alive(service, instance) if instance else f"{keys.ROOT}/alive/{service}/*")
    return out


def _check_estimator(est: EstimatorSpec) -> list[str]:
    if not any(est.kind == p.name or est.kind in p.mc for p in plugins().values()):
        return [f".kind: no installed plugin names an estimator {est.kind!r} (shared.plugins)"]
    module = mc_module(est.kind)
    if module is None:
        return []  # no mc module: fine for playing, ``fixstream mc`` says so
    mc = importlib.import_module(module)
    model = getattr(mc, "Params", None)
    if model is None:
        return []
    try:
        model.model_validate(est.params, strict=True)
    except ValidationError as exc:
        return [f".params{_path(e['loc'])}: {_msg(e)}" for e in exc.errors()]
    return []


def _path(loc: tuple[int | str, ...]) -> str:
    """``("sensors", 1, "sigma_m")`` -> ``.sensors[1].sigma_m``."""
    return "".join(f"[{part}]" if isinstance(part, int) else f".{part}" for part in loc)


def _msg(error: Any) -> str:
    msg = str(error.get("msg", "invalid"))
    msg = msg.removeprefix("Value error, ")
    kind = error.get("type", "")
    if kind not in ("missing", "extra_forbidden", "value_error", "assertion_error") and "input" in error:
        text = repr(error["input"])
        msg += f" (got {text[:80]}{'...' if len(text) > 80 else ''})"
    return msg


def format_validation_error(exc: ValidationError, source: str) -> str:
    lines = []
    for e in exc.errors():
        where = _path(e["loc"]).removeprefix(".")
        for line in _msg(e).splitlines():
            if line.startswith((".", "[")):  # a nested path from a plugin's own model
                lines.append(f"{source}: {where}{line}")
            else:
                lines.append(f"{source}: {where}: {line}" if where else f"{source}: {line}")
    return "\n".join(lines)


def parse_scenario(data: Any, source: str = "<scenario>") -> Scenario:
    """Validate an already-parsed YAML document."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    try:
        return Scenario.model_validate(data, strict=True)
    except ValidationError as exc:
        raise ScenarioError(format_validation_error(exc, source)) from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file (raises :class:`ScenarioError`)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        problem = f"not UTF-8 text (byte {exc.start}: {exc.reason}); a scenario is a YAML file"
        raise ScenarioError(f"{p}: {problem}") from None
    try:
        data = yaml_numbers.load(text)
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{p}: invalid YAML: {_yaml_problem(exc)}") from None
    return parse_scenario(data, str(p))


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """One line for a YAML error: what went wrong and where (line and column from 1), not yaml's multi-line
    excerpt of the file."""
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem_mark is not None:
        mark = exc.problem_mark
        return f"line {mark.line + 1}, column {mark.column + 1}: {exc.problem or exc.context or 'syntax error'}"
    return " ".join(str(exc).split())


def default_dir() -> Path:
    return Path(os.environ.get(DEFAULT_DIR_ENV, "scenarios"))


def scenario_files(directory: str | Path) -> list[Path]:
    d = Path(directory)
    return sorted(p for p in d.iterdir() if p.suffix in SUFFIXES and p.is_file()) if d.is_dir() else []


def load_by_name(name: str, directory: str | Path | None = None) -> Scenario:
    """The scenario called ``name`` in the scenario directory, for names that arrive over the network (a start
    marker's): a bare name only, looked up only inside ``directory`` (never a path, so a marker naming
    ``/etc/passwd`` or ``../x`` opens nothing). ScenarioError otherwise."""
    if not name or any(c in name for c in "/\\\0") or name.startswith(".") or len(name) > 256:
        raise ScenarioError(f"{name!r} is not a scenario name (names only, no paths)")
    d = Path(directory) if directory is not None else default_dir()
    for suffix in SUFFIXES:
        candidate = d / f"{name}{suffix}"
        if candidate.is_file():
            return load_scenario(candidate)
    for f in scenario_files(d):
        try:
            data = yaml_numbers.load(f.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError):  # load_scenario says what is wrong with it
            continue
        if isinstance(data, dict) and data.get("name") == name:
            return load_scenario(f)
    raise ScenarioError(f"no scenario named {name!r} in {d}/")


def resolve(name_or_path: str | Path, directory: str | Path | None = None) -> Path:
    """A scenario file from a path, a file stem in ``directory`` or a scenario ``name`` in ``directory``."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    d = Path(directory) if directory is not None else default_dir()
    for suffix in SUFFIXES:
        candidate = d / f"{name_or_path}{suffix}"
        if candidate.is_file():
            return candidate
    for f in scenario_files(d):
        try:
            data = yaml_numbers.load(f.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError):  # load_scenario says what is wrong with it
            continue
        if isinstance(data, dict) and data.get("name") == str(name_or_path):
            return f
    raise ScenarioError(f"{name_or_path}: no such scenario file, and no scenario of that name in {d}/")
