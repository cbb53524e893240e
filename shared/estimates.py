"""Building the :class:`~schemas.estimate.GaussianEstimate` block every fix and track carries (issue 19, item 6).

Every service builds its blocks through :func:`gaussian` with the :class:`~schemas.estimate.Layout` (component
names and units) that the message field declares in the schema (``schemas/estimate.py``: the common layouts;
an estimator's own in its schema module), so the vocabulary is written once. Position components are named after
the frame's axes; :func:`shared.foxglove.frames.gaussian_position` reads them back by name.
"""

from __future__ import annotations

from schemas.estimate import CV_STATE, HORIZONTAL, POSITION, VELOCITY, GaussianEstimate, Layout

from .models import built


def gaussian(
    frame: str,
    layout: Layout,
    mean: list[float],
    covariance: list[list[float]],
    *,
    validate: bool = True,
) -> GaussianEstimate:
    """The block of ``mean`` and ``covariance`` (lists of Python floats, as published) in ``frame``.

    ``validate=False`` skips the schema's checks (the O(n^3) positive semi-definite test among them) for the
    services that build from values valid by construction and validate only on request, as they already did for
    their covariance fields; the instance is then the one ``model_construct`` builds (:func:`shared.models.built`:
    about 2 µs, the PCL tracker builds two per track and scan). The values are stored as given either way."""
    components, units = list(layout.components), list(layout.units)
    if validate:
        return GaussianEstimate(frame=frame, components=components, units=units, mean=mean, covariance=covariance)
    values = {"frame": frame, "components": components, "units": units, "mean": mean, "covariance": covariance}
    return built(GaussianEstimate, values)


__all__ = ["CV_STATE", "HORIZONTAL", "POSITION", "VELOCITY", "Layout", "gaussian"]
