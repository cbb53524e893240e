"""terrain_nav's FIXSTREAM_TERRAIN_NAV_PRESET: the shorthand every other estimator has (FIXSTREAM_<ESTIMATOR>_PRESET),
which compose.yaml documents for terrain_nav too; before, the variable was only a compose interpolation, and a
service that inherited it warned that it was not a setting."""

from __future__ import annotations

import logging

import pytest
from pydantic import ValidationError

from services.terrain_nav.config import PRESETS, TerrainNavConfig
from services.terrain_nav.service import TerrainNavSettings


@pytest.fixture(autouse=True)
def _env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_MAP_PATH", "maps/x.npy")


def test_the_preset_shorthand_selects_the_papers_configuration(monkeypatch: pytest.MonkeyPatch) -> None:
    assert TerrainNavSettings.load(instance="t").core.preset == "robust"
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_PRESET", "paper")
    core = TerrainNavSettings.load(instance="t").core
    paper = TerrainNavConfig(preset="paper")
    assert core == paper
    assert all(getattr(core, name) != value for name, value in PRESETS["robust"].items())  # none of robust's left


def test_explicit_core_parameters_still_win_and_a_conflict_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_PRESET", "paper")
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_CORE__REFINE", "true")
    core = TerrainNavSettings.load(instance="t").core
    assert core.preset == "paper" and core.refine is True
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_CORE__PRESET", "robust")
    with pytest.raises(ValidationError, match="disagree"):
        TerrainNavSettings.load(instance="t")


def test_the_shorthand_is_no_unknown_variable(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_PRESET", "robust")
    with caplog.at_level(logging.WARNING):
        TerrainNavSettings.load(instance="t")
    assert not [r for r in caplog.records if "FIXSTREAM_TERRAIN_NAV_PRESET" in r.getMessage()]
