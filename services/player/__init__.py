"""Scenario player: simulates truth and sensor streams from a scenario YAML (or replays an MCAP) onto Zenoh."""
