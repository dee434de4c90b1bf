"""Arguments of the wrong kind refused in words, before they fail deep inside.

Found as an API user: ``fit_scene(image, None, render)`` said "'NoneType' object has no
attribute 'modality'", swapped settings the same, ``diagnose(..., rng=0)`` "'int'
object has no attribute 'standard_normal'".
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["require_argument"]


def require_argument(
    value: Any, expected: type | tuple[type, ...], call: str, *, optional: bool = False
) -> None:
    """Refuse an argument of the wrong kind with a ``TypeError`` that names it.

    Parameters
    ----------
    value
        The argument given.
    expected
        The class(es) it must be an instance of; the first names the fix.
    call
        How the message names the argument, e.g. ``"fit_scene(microscope=...)"``.
    optional
        ``None`` is accepted too.

    Raises
    ------
    TypeError
        Naming the argument, the class it needs and what was given.
    """
    kinds = expected if isinstance(expected, tuple) else (expected,)
    if isinstance(value, kinds) or (optional and value is None):
        return
    needed = " or ".join(kind.__name__ for kind in kinds)
    given = type(value).__name__
    if kinds[0] is np.random.Generator:
        fix = f"numpy.random.default_rng({value!r})" if isinstance(value, int) else (
            "numpy.random.default_rng(seed)"
        )
    elif isinstance(value, dict):
        fix = f"{kinds[0].__name__}(**that_dict)"
    else:
        fix = f"{kinds[0].__name__}(...)"
    raise TypeError(
        f"{call} needs {needed}{' or None' * optional}, got {given}: pass {fix} "
        "(check the order of the arguments)"
    )
