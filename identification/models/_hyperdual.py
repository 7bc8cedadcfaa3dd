"""Second-order forward-mode differentiation for the identification (directions x parameters).

A ``HyperDual`` carries a value ``v`` and three kinds of derivatives:

``a`` : shape ``(k,) + v.shape``
    directional derivatives along k directions of the inputs (the virtual strains);
``b`` : shape ``(m,) + v.shape``
    derivatives with respect to m parameters;
``ab`` : shape ``(k, m) + v.shape``
    the mixed second derivatives.

Any of them may be ``None`` (identically zero). A strain energy written as a plain numpy expression
(``_base.py``: arithmetic, ``exp/log/sqrt/sin/cos``, ``power`` by a constant, ``np.where``, ``np.real``)
evaluated on these numbers gives, in one pass, the internal virtual work of every virtual field
(``a``: W differentiated along each field's virtual strain) and its exact derivative with respect to
the nonlinear parameters (``ab``): the residuals and the Jacobian of the virtual-work balance.
The second-order rule for a function f is ``ab -> f' ab + f'' a (x) b``.
"""

from __future__ import annotations

import numpy as np

from ._dual import apply_ufunc

__all__ = ["HyperDual", "seed_directions", "seed_parameters"]


def _add(x, y):
    if x is None:
        return y
    if y is None:
        return x
    return x + y


def _scale(x, s):
    return None if x is None else x * s


def _outer(a, b):
    """``a (k, ...) (x) b (m, ...) -> (k, m, ...)``, None if either is zero."""
    if a is None or b is None:
        return None
    return a[:, None] * b[None]


class HyperDual:
    __array_priority__ = 1000
    __slots__ = ("v", "a", "b", "ab")
    order = 2

    def __init__(self, v, a=None, b=None, ab=None):
        self.v = v
        self.a = a
        self.b = b
        self.ab = ab

    # -- arithmetic ------------------------------------------------------------------------
    def __add__(self, o):
        if isinstance(o, HyperDual):
            return HyperDual(self.v + o.v, _add(self.a, o.a), _add(self.b, o.b), _add(self.ab, o.ab))
        return HyperDual(self.v + o, self.a, self.b, self.ab)

    __radd__ = __add__

    def __neg__(self):
        return HyperDual(-self.v, _scale(self.a, -1.0), _scale(self.b, -1.0), _scale(self.ab, -1.0))

    def __sub__(self, o):
        return self + (-o)

    def __rsub__(self, o):
        return (-self) + o

    def __mul__(self, o):
        if not isinstance(o, HyperDual):
            return HyperDual(self.v * o, _scale(self.a, o), _scale(self.b, o), _scale(self.ab, o))
        ab = _add(_add(_scale(self.ab, o.v), _scale(o.ab, self.v)),
                  _add(_outer(self.a, o.b), _outer(o.a, self.b)))
        return HyperDual(self.v * o.v, _add(_scale(self.a, o.v), _scale(o.a, self.v)),
                         _add(_scale(self.b, o.v), _scale(o.b, self.v)), ab)

    __rmul__ = __mul__

    def __truediv__(self, o):
        if isinstance(o, HyperDual):
            return self * o._reciprocal()
        return self * (1.0 / o)

    def __rtruediv__(self, o):
        return self._reciprocal() * o

    def _reciprocal(self):
        inv = 1.0 / self.v
        return self._chain(inv, -inv * inv, 2.0 * inv * inv * inv)

    def __pow__(self, n):
        if isinstance(n, HyperDual):
            raise TypeError("HyperDual ** HyperDual is not supported")
        return self._chain(self.v**n, n * self.v ** (n - 1), n * (n - 1) * self.v ** (n - 2))

    def _chain(self, value, d1, d2):
        """f(self) given f = value, f' = d1, f'' = d2 at self.v."""
        ab = _add(_scale(self.ab, d1), _scale(_outer(self.a, self.b), d2))
        return HyperDual(value, _scale(self.a, d1), _scale(self.b, d1), ab)

    # -- numpy protocol ----------------------------------------------------------------------
    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if method != "__call__" or kwargs:
            return NotImplemented
        return apply_ufunc(HyperDual, ufunc, inputs)

    def __array_function__(self, func, types, args, kwargs):
        if func is np.real:
            v = args[0].v if isinstance(args[0], HyperDual) else args[0]
            return np.real(v)
        if func is np.where and len(args) == 3 and not kwargs:
            cond, x, y = args
            parts = []
            for name in ("v", "a", "b", "ab"):
                px = getattr(x, name) if isinstance(x, HyperDual) else (x if name == "v" else None)
                py = getattr(y, name) if isinstance(y, HyperDual) else (y if name == "v" else None)
                if px is None and py is None:
                    parts.append(None)
                else:
                    parts.append(np.where(cond, 0.0 if px is None else px, 0.0 if py is None else py))
            return HyperDual(*parts)
        return NotImplemented


def seed_directions(values: np.ndarray, directions: np.ndarray) -> HyperDual:
    """An input of value ``values (...)`` varying along ``directions (k, ...)``."""
    return HyperDual(np.asarray(values, dtype=float), np.asarray(directions, dtype=float))


def seed_parameters(values, ndim: int) -> list[HyperDual]:
    """The m parameters ``values`` as independent HyperDuals with ``ndim`` trailing unit axes."""
    values = np.asarray(values, dtype=float)
    m = len(values)
    unit = (1,) * ndim
    eye = np.eye(m).reshape((m, m) + unit)
    return [HyperDual(np.full(unit, v), b=eye[j]) for j, v in enumerate(values)]
