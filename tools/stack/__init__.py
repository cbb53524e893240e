"""The stack runner behind ``fixstream up``: compose.yaml parsed and run as local processes.

``compose``: parse and normalise a compose file; ``interpolate``: compose variable interpolation and
``.env`` files; ``plan``: services to local commands (embedded router, loopback endpoints, bind-volume
paths); ``supervisor``: start in order, prefix output, readiness, ordered shutdown; ``console``: output.
"""

from __future__ import annotations

from .compose import ComposeError, ComposeProject, ServiceSpec, find_compose_file, load_compose
from .interpolate import InterpolationError, interpolate, parse_env_file
from .plan import ProcessSpec, StackPlan, plan_stack
from .supervisor import StackResult, Supervisor

__all__ = [
    "ComposeError",
    "ComposeProject",
    "InterpolationError",
    "ProcessSpec",
    "ServiceSpec",
    "StackPlan",
    "StackResult",
    "Supervisor",
    "find_compose_file",
    "interpolate",
    "load_compose",
    "parse_env_file",
    "plan_stack",
]
