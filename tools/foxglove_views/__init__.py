"""Foxglove view converters of estimators whose folders cannot hold them yet (see each module)."""
