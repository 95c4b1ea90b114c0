"""Field types shared by the configuration schemas, so that a constraint is written once.

Each is a ``typing.Annotated`` float that pydantic validates, rejecting NaN and infinities (an
optional value is written ``PositiveFloat | None``); units are in the field names, never here.

=======================  ==============  ====================================================
type                     accepts         used for
=======================  ==============  ====================================================
:data:`FiniteFloat`      any finite      temperatures in degC, signed angles, coefficients
:data:`PositiveFloat`    ``> 0``         lengths, times, scales, sigmas that must not vanish
:data:`NonNegativeFloat` ``>= 0``        margins, noise levels that may be switched off
:data:`UnitInterval`     ``[0, 1]``      fractions that may be 0 or 1
:data:`PositiveFraction` ``(0, 1]``      fractions that must not be 0 (a transmission, a
                                         headroom: a zero would divide or empty a signal)
=======================  ==============  ====================================================

:data:`PositiveCount` is an ``int >= 1`` that refuses a boolean (pydantic would read ``true``
as 1).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BeforeValidator, Field

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
UnitInterval = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
PositiveFraction = Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)]


def _not_bool(v: Any) -> Any:
    if isinstance(v, bool):
        raise ValueError(f"a whole number, not the boolean {str(v).lower()}")
    return v


PositiveCount = Annotated[int, BeforeValidator(_not_bool), Field(ge=1)]

__all__ = ["FiniteFloat", "NonNegativeFloat", "PositiveCount", "PositiveFloat",
           "PositiveFraction", "UnitInterval"]
