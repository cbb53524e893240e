"""Configuration from environment variables (and an optional YAML/JSON file), validated by pydantic.

Every process reads :class:`ZenohSettings` (prefix ``FIXSTREAM_ZENOH_``) and its own settings class
derived from :class:`ServiceSettings` (prefix ``FIXSTREAM_``). Lists are given as JSON or as
comma-separated strings: ``FIXSTREAM_ZENOH_CONNECT=tcp/127.0.0.1:7447,tcp/10.0.0.2:7447``.
A file named by ``FIXSTREAM_CONFIG_FILE`` supplies defaults that environment variables override.
"""

from __future__ import annotations

import difflib
import json
import logging
import os
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import yaml
from pydantic import BaseModel, BeforeValidator, Field, ValidationError, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from .errors import StartupError
from .keys import ROOT
from .local_stack import default_connect, default_tls

log = logging.getLogger(__name__)


def _split_list(value: Any) -> Any:
    if isinstance(value, str):
        text = value.strip()
        if not text:
            return []
        if text.startswith("["):
            return json.loads(text)
        return [part.strip() for part in text.split(",") if part.strip()]
    return value


StrList = Annotated[list[str], NoDecode, BeforeValidator(_split_list)]


class ZenohSettings(BaseSettings):
    """How a process joins the Zenoh network."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_ZENOH_", extra="ignore")

    mode: Literal["client", "peer", "router"] = "client"
    connect: StrList = Field(
        default_factory=default_connect,
        description="endpoints to connect to; default: the running local stack (fixstream up), else tcp/127.0.0.1:7447",
    )
    listen: StrList = Field(default_factory=list)
    multicast_scouting: bool = False
    config_file: Path | None = Field(default=None, description="a zenoh JSON5 config used as the base")
    tls_root_ca: Path | None = Field(
        default=None, description="CA certificate that signed the router's (and, with mTLS, every) certificate"
    )
    tls_cert: Path | None = Field(default=None, description="this process's certificate: its identity (mutual TLS)")
    tls_key: Path | None = Field(default=None, description="the private key of tls_cert")
    block_close_s: float | None = Field(
        default=None,
        gt=0.0,
        description="how long a blocking (CongestionControl.BLOCK) message may wait for a full link queue before Zenoh"
        " closes the link, s (None: Zenoh's 5 s). Routers wait longer (fixstream router: 60 s), so a subscriber that is"
        " slow for a while back-pressures the publishers instead of losing its session and what was in flight",
    )
    shared_memory: bool = Field(
        default=False,
        description="Zenoh's implicit shared-memory transport for payloads of 3 KiB and more between local processes."
        " Off by default: a buffer a busy subscriber has not read in time is invalidated by Zenoh's watchdog and the"
        " message vanishes without a trace (measured: 7 of 61 PCL scans lost by the recorder on the demo at --rate 0;"
        " eclipse-zenoh/zenoh#2628)",
    )
    recovery_keys: StrList = Field(
        default_factory=lambda: [f"{ROOT}/group/**", f"{ROOT}/scenario/**"],
        description="key expressions published with a cache and subscribed with recovery (zenoh-ext), so that what a"
        " router outage loses on them comes back once the router does: the control streams (shared/recovery.py)."
        " Empty: plain publishers and subscribers everywhere",
    )
    recovery_cache_samples: int = Field(
        default=64, ge=1, description="samples a publisher on a recovery key keeps for subscribers that missed them"
    )
    recovery_heartbeat_s: float = Field(
        default=0.5,
        gt=0.0,
        description="how often a publisher on a recovery key announces its last sample's number, s (a lost last"
        " sample is seen missing within this time of the router's return)",
    )
    connect_timeout_s: float = Field(
        default=30.0,
        ge=-1.0,
        description="how long opening a session keeps retrying its connect endpoints, s (-1: forever, 0: one try);"
        " once open, a session reconnects by itself whenever its router comes back",
    )

    @model_validator(mode="after")
    def _stack_identity(self) -> ZenohSettings:
        """With no endpoint and no certificate configured, a client attaching to a secure local stack (fixstream up
        --secure) takes the read-only client identity that stack announced."""
        unset = {"connect", "tls_root_ca", "tls_cert", "tls_key"}.isdisjoint(self.model_fields_set)
        if unset and self.mode == "client":
            tls = default_tls()
            if tls:
                for name in ("tls_root_ca", "tls_cert", "tls_key"):
                    object.__setattr__(self, name, Path(tls[name]))
        return self


def _file_defaults() -> dict[str, Any]:
    """The settings of ``$FIXSTREAM_CONFIG_FILE`` (none if unset); :class:`StartupError` (one line) for a file that
    cannot be read, is not YAML/JSON or is not a mapping of settings."""
    path = os.environ.get("FIXSTREAM_CONFIG_FILE")
    if not path:
        return {}
    where = f"FIXSTREAM_CONFIG_FILE={path}"
    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as exc:
        raise StartupError(f"{where}: cannot read: {exc.strerror or exc}") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise StartupError(f"{where}: not valid YAML/JSON: {' '.join(str(exc).split())}") from None
    if data is None:  # an empty file
        return {}
    if not isinstance(data, dict):
        raise StartupError(f"{where}: expected a mapping of settings at the top level, got {type(data).__name__}")
    return data


def _candidates(cls: type[BaseSettings], delimiter: str) -> list[str]:
    """The variable names (without the prefix) ``cls`` reads: its fields and, with a nested delimiter, its nested
    models' fields (``CORE__PRESET``)."""
    names = []
    for name, info in cls.model_fields.items():
        names.append(name.upper())
        sub = info.annotation
        if delimiter and isinstance(sub, type) and issubclass(sub, BaseModel):
            names.extend(f"{name}{delimiter}{inner}".upper() for inner in sub.model_fields)
    return names


#: unknown environment variables already warned about (once per process)
_warned_env: set[str] = set()


def _warn_unknown_env(cls: type[BaseSettings]) -> None:
    """One warning per ``FIXSTREAM_<SERVICE>_*`` variable that no field of ``cls`` reads, naming the nearest one.

    Only a service's own prefix is looked at (``FIXSTREAM_LBL_NAV_`` for lbl_nav): ``FIXSTREAM_ZENOH_*``,
    ``FIXSTREAM_LOG_*``, the other services' variables and the base settings (``FIXSTREAM_INSTANCE``) share the
    environment of a stack and are not this class's to judge."""
    prefix = str(cls.model_config.get("env_prefix") or "").upper()
    if prefix in ("", "FIXSTREAM_"):
        return
    delimiter = str(cls.model_config.get("env_nested_delimiter") or "").upper()
    known = {name.upper() for name in cls.model_fields}
    for var in sorted(os.environ):
        upper = var.upper()
        if not upper.startswith(prefix) or upper in _warned_env:
            continue
        field = upper[len(prefix) :]
        if delimiter:
            field = field.split(delimiter, 1)[0]
        if field in known:
            continue
        _warned_env.add(upper)
        near = difflib.get_close_matches(upper[len(prefix) :], _candidates(cls, delimiter), n=1)
        hint = f"; did you mean {prefix}{near[0]}?" if near else ""
        log.warning("%s is not a setting of %s and is ignored%s", var, cls.__name__, hint)


class ServiceSettings(BaseSettings):
    """Settings every service has. Subclasses add their own fields (same ``FIXSTREAM_`` prefix)."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_", extra="ignore")

    instance: str = Field(default="default", description="instance name, the last chunk of its keys")
    reset_on_scenario_end: bool = Field(
        default=True,
        description="start a fresh core (a new session) once the run the player's end marker announced has ended, so "
        "the next run, whose stamps start again from 0, is accepted (estimators; the recorder has no core)",
    )
    queue_size: int = Field(default=100_000, ge=1, description="inbound samples held before back-pressure")
    queue_max_bytes: int = Field(
        default=256 << 20, ge=1 << 16, description="inbound payload bytes held before back-pressure, bytes"
    )
    max_payload_bytes: int = Field(
        default=1 << 20,
        ge=1 << 10,
        le=4 << 20,
        description="a larger payload is refused unread (payload_too_large), bytes",
    )
    enqueue_block_s: float = Field(
        default=1.0,
        ge=0.0,
        le=50.0,
        description="longest a full queue holds Zenoh's delivery thread (slowing blocking publishers) before samples"
        " are dropped and counted (queue_full); below the router's 60 s wait before it closes a blocked link, so a busy"
        " service keeps its session, s",
    )
    end_wait_s: float = Field(
        default=5.0,
        ge=0.0,
        description="wall time the end of a scenario waits, after the last counted sample, for messages its end"
        " marker announced but which have not arrived (lost, or the publisher died), s",
    )

    @classmethod
    def load(cls, **overrides: Any) -> ServiceSettings:
        """File defaults < environment < explicit overrides. A missing or invalid setting raises pydantic's
        ValidationError; the command line turns it into one line naming the environment variable
        (:func:`settings_error_message`)."""
        _warn_unknown_env(cls)
        file_data = {k: v for k, v in _file_defaults().items() if k in cls.model_fields}
        env_view = cls()  # environment (and defaults)
        merged = {**file_data, **env_view.model_dump(exclude_unset=True), **overrides}
        return cls(**merged)


def _settings_classes(root: type[BaseSettings] = BaseSettings) -> dict[str, type[BaseSettings]]:
    found: dict[str, type[BaseSettings]] = {}
    for sub in root.__subclasses__():
        found[sub.__name__] = sub
        found.update(_settings_classes(sub))
    return found


def env_var_of(cls: type[BaseSettings], loc: tuple[int | str, ...]) -> str:
    """The environment variable that sets the field at ``loc`` of settings class ``cls``."""
    prefix = str(cls.model_config.get("env_prefix") or "")
    delimiter = str(cls.model_config.get("env_nested_delimiter") or "__")
    return (prefix + delimiter.join(str(part) for part in loc)).upper()


def settings_error_message(exc: ValidationError) -> str:
    """One line for a settings validation error: each bad field as its environment variable and the problem."""
    cls = _settings_classes().get(exc.title)
    parts = []
    for err in exc.errors(include_url=False):
        loc = tuple(err.get("loc", ()))
        name = env_var_of(cls, loc) if cls is not None and loc else ".".join(map(str, loc)) or exc.title
        problem = "missing (required)" if err.get("type") == "missing" else str(err.get("msg"))
        parts.append(f"{name}: {problem}")
    return f"invalid settings ({exc.title}): " + "; ".join(parts)


ConfigT = TypeVar("ConfigT", bound=BaseModel)


def core_config_of(settings: BaseModel, config_cls: type[ConfigT], **fixed: Any) -> ConfigT:
    """The core configuration a service's settings embed: every ``config_cls`` field read from ``settings`` (a
    settings class that subclasses both ServiceSettings and the core's config model), then ``fixed`` (the
    instance's own id, which the service decides), validated by ``config_cls``."""
    fields = {name: getattr(settings, name) for name in config_cls.model_fields}
    fields.update(fixed)
    return config_cls(**fields)
