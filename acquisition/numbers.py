"""Numbers as text files write them: one strict reading for every CSV reader.

Python's ``float()`` accepts more than a table should: ``1_0.5`` (read as 10.5), digits of other scripts
(``"١٢"``), surrounding whitespace. :func:`strict_float` accepts decimal notation with an optional exponent,
and ``nan``/``inf``/``infinity`` (any case, signed), nothing else.
"""

from __future__ import annotations

import re

__all__ = ["strict_float"]

_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:nan|inf|infinity)",
                     re.IGNORECASE | re.ASCII)


def strict_float(text: str) -> float:
    """``text`` as a float, or a ValueError naming it when it is not a plain decimal number."""
    if not _NUMBER.fullmatch(text):
        raise ValueError(f"{text!r} is not a number")
    return float(text)
