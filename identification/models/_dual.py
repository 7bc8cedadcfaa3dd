"""Forward-mode automatic differentiation with vector dual numbers (the models' shared derivative).

A ``Dual`` carries a value ``v`` (any shape) and its derivatives ``d`` (shape ``(k,) + v.shape``)
with respect to k independent inputs. Arithmetic, the numpy ufuncs the models use (exp, log,
sqrt, sin, cos, power with a constant exponent) and ``np.where`` / ``np.real`` propagate them, so
a strain energy written as a plain numpy expression yields its gradient in one evaluation,
exactly (no step size).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Dual", "seed"]


def _val(x):
    return x.v if isinstance(x, Dual) else x


def _elementary(ufunc, v):
    """(f, f', f'') of the elementary functions the models use, at v; None for others."""
    if ufunc is np.exp:
        e = np.exp(v)
        return e, e, e
    if ufunc is np.log:
        inv = 1.0 / v
        return np.log(v), inv, -inv * inv
    if ufunc is np.sqrt:
        r = np.sqrt(v)
        return r, 0.5 / r, -0.25 / (r * r * r)
    if ufunc is np.sin:
        sn, cs = np.sin(v), np.cos(v)
        return sn, cs, -sn
    if ufunc is np.cos:
        sn, cs = np.sin(v), np.cos(v)
        return cs, -sn, -cs
    return None


_REFLECTED = {np.add: "__radd__", np.subtract: "__rsub__", np.multiply: "__rmul__", np.true_divide: "__rtruediv__"}
_FORWARD = {np.add: "__add__", np.subtract: "__sub__", np.multiply: "__mul__", np.true_divide: "__truediv__"}


def apply_ufunc(cls, ufunc, inputs):
    """The numpy ufuncs on dual numbers of class ``cls`` (shared by ``Dual`` and ``HyperDual``).

    Arithmetic goes through the class operators; elementary functions through ``x._chain`` with the
    derivatives up to the class's ``order``.
    """
    if ufunc in _FORWARD:
        x, y = inputs
        return getattr(x, _FORWARD[ufunc])(y) if isinstance(x, cls) else getattr(y, _REFLECTED[ufunc])(x)
    if ufunc is np.power and isinstance(inputs[0], cls):
        return inputs[0] ** inputs[1]
    x = inputs[0]
    if len(inputs) != 1 or not isinstance(x, cls):
        return NotImplemented
    if ufunc is np.negative:
        return -x
    d = _elementary(ufunc, x.v)
    return NotImplemented if d is None else x._chain(*d[: cls.order + 1])


class Dual:
    __array_priority__ = 1000
    order = 1

    def __init__(self, v, d):
        self.v = v
        self.d = d

    # -- arithmetic ------------------------------------------------------------------------
    def __add__(self, o):
        if isinstance(o, Dual):
            return Dual(self.v + o.v, self.d + o.d)
        v = self.v + o
        return Dual(v, np.broadcast_to(self.d, self.d.shape[:1] + np.shape(v)))

    __radd__ = __add__

    def __neg__(self):
        return Dual(-self.v, -self.d)

    def __sub__(self, o):
        return self + (-o)

    def __rsub__(self, o):
        return (-self) + o

    def __mul__(self, o):
        if isinstance(o, Dual):
            return Dual(self.v * o.v, self.d * o.v + self.v * o.d)
        return Dual(self.v * o, self.d * o)

    __rmul__ = __mul__

    def __truediv__(self, o):
        if isinstance(o, Dual):
            return self * o._reciprocal()
        return Dual(self.v / o, self.d / o)

    def __rtruediv__(self, o):
        return self._reciprocal() * o

    def _reciprocal(self):
        inv = 1.0 / self.v
        return Dual(inv, -self.d * (inv * inv))

    def __pow__(self, n):
        if isinstance(n, Dual):
            raise TypeError("Dual ** Dual is not supported")
        return Dual(self.v**n, self.d * (n * self.v ** (n - 1)))

    def _chain(self, value, slope):
        return Dual(value, self.d * slope)

    # -- numpy protocol ----------------------------------------------------------------------
    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if method != "__call__" or kwargs:
            return NotImplemented
        return apply_ufunc(Dual, ufunc, inputs)

    def __array_function__(self, func, types, args, kwargs):
        if func is np.real:
            return _val(args[0])
        if func is np.where and len(args) == 3 and not kwargs:
            cond, a, b = args
            k = (a if isinstance(a, Dual) else b).d.shape[0]
            va, vb = _val(a), _val(b)
            v = np.where(cond, va, vb)
            da = a.d if isinstance(a, Dual) else np.zeros((k,) + np.shape(v))
            db = b.d if isinstance(b, Dual) else np.zeros((k,) + np.shape(v))
            return Dual(v, np.where(cond, da, db))
        return NotImplemented


def seed(*values):
    """Independent duals for the given arrays (broadcast to one shape): derivative k of input k is 1."""
    arrays = np.broadcast_arrays(*[np.asarray(v, dtype=float) for v in values])
    k = len(arrays)
    out = []
    for i, a in enumerate(arrays):
        d = np.zeros((k,) + a.shape)
        d[i] = 1.0
        out.append(Dual(a, d))
    return out
