"""Building a message model from values known to be valid, without pydantic's validation or its per-field loop.

The services that publish at high rate (the PCL tracker's scan reports, lbl_nav's Monte-Carlo fixes, the Gaussian
estimate blocks of :mod:`shared.estimates`) build their outputs from values checked or valid by construction and
let consumers validate on decode. :func:`built` makes the instance ``model_construct`` would make when every field
is given (the same ``__dict__`` and fields set, no extra, no private attributes: the schemas have none) in a few
microseconds instead of ``model_construct``'s loop over the fields (about six times as long).
"""

from __future__ import annotations

from typing import Any, TypeVar

from pydantic import BaseModel

M = TypeVar("M", bound=BaseModel)

_setattr = object.__setattr__


def built(cls: type[M], values: dict[str, Any]) -> M:
    """An instance of ``cls`` holding ``values`` (every field of the model given), not validated."""
    obj = cls.__new__(cls)
    _setattr(obj, "__dict__", values)
    _setattr(obj, "__pydantic_fields_set__", set(values))
    _setattr(obj, "__pydantic_extra__", None)
    _setattr(obj, "__pydantic_private__", None)
    return obj


__all__ = ["built"]
