"""Symbolic values that turn homofac's array code into shader code (one formula, two targets).

The mappers (:mod:`homofac.param.mappers`), projections (:mod:`homofac.param.projections`) and sphere
helpers (:mod:`homofac.sphere`) are written against an array namespace ``xp`` that follows their
input (:func:`homofac.sphere.namespace`). Called with :class:`Expr` values instead of arrays, the very
same functions record the operations they perform as an expression graph, which
:mod:`homofac.shader.languages` prints as GLSL, GLSL ES, HLSL, MSL or WGSL. Nothing is written twice:
the GPU evaluates the formula the solver fitted against (the tests compare both on random inputs).

Supported: the scalar types ``float``, ``int``, ``bool`` and ``vec3``; arithmetic with Python numbers
and NumPy constants; comparisons and logic on scalars; ``[..., i]`` / ``[..., i:i+1]`` components,
``[..., None]`` (a scalar broadcasts by itself); ``astype``; and the namespace functions in
:class:`Namespace` (``where``, ``maximum``, ``minimum``, ``abs``, ``sqrt``, ``floor``, ``clip``, ``sum``
over the last axis, ``stack`` of three scalars, ``cross``, ``asarray`` of constants and of constant
tables indexed by an int). Python control flow on a symbolic value is an error: write it as ``where``.
"""

from __future__ import annotations

import hashlib
import itertools
import weakref
from typing import Any

import numpy as np

from ..errors import HomofacError

TYPES = ("bool", "int", "float", "vec3")
_ids = itertools.count()


class Expr:
    """A node of the expression graph: an operation ``op`` on ``args`` giving a value of ``type``.

    Ops: ``input`` (args: name), ``const`` (args: value), ``table`` (args: name, (N, 3) values),
    ``index`` (table, int), ``bin`` (operator, a, b), ``un`` (operator, a), ``call`` (function, *args),
    ``select`` (condition, if true, if false), ``comp`` (a, i), ``vec3`` (x, y, z), ``cast`` (a).
    """

    __slots__ = ("op", "args", "type", "id", "__weakref__")

    def __new__(cls, op: str, args: tuple, type: str):
        # hash-consing: a structurally equal node is the same node, so the printer shares it
        # (the common subexpressions of the traced formulas become one local variable)
        if type not in TYPES:
            raise HomofacError(f"shader expression type {type!r} is not one of {', '.join(TYPES)}")
        key = (op, type) + tuple(_key(a) for a in args)
        node = _INTERNED.get(key)
        if node is None:
            node = object.__new__(cls)
            node.op, node.args, node.type, node.id = op, args, type, next(_ids)
            _INTERNED[key] = node
        return node

    # --- construction helpers -------------------------------------------------------------------
    @staticmethod
    def input(name: str, type: str) -> "Expr":
        return Expr("input", (name,), type)

    @staticmethod
    def const(value: Any, type: str | None = None) -> "Expr":
        if type is None:
            type = _type_of_value(value)
        if type == "vec3":
            value = tuple(float(x) for x in np.asarray(value, np.float64).reshape(3))
        elif type == "float":
            value = float(value)
        elif type == "int":
            value = int(value)
        elif type == "bool":
            value = bool(value)
        return Expr("const", (value,), type)

    @property
    def is_const(self) -> bool:
        return self.op == "const"

    @property
    def dtype(self):
        return {"float": np.dtype(np.float32), "vec3": np.dtype(np.float32), "int": np.dtype(np.int32),
                "bool": np.dtype(bool)}[self.type]

    @property
    def shape(self) -> tuple:
        return ()

    @property
    def ndim(self) -> int:
        return 0

    def astype(self, dtype) -> "Expr":
        kind = np.dtype(dtype).kind
        target = {"i": "int", "u": "int", "f": "float", "b": "bool"}[kind]
        if self.type == "vec3" and target == "float":
            return self
        return _cast(self, target)

    def __bool__(self):
        raise HomofacError("a symbolic shader value has no truth value: write Python `if` as xp.where(...)")

    def __repr__(self) -> str:
        return f"Expr({self.op}, {self.type}, #{self.id})"

    # --- components ---------------------------------------------------------------------------
    def __getitem__(self, key) -> "Expr":
        key = key if isinstance(key, tuple) else (key,)
        if key and key[0] is Ellipsis:
            key = key[1:]
        if len(key) != 1:
            raise HomofacError(f"unsupported symbolic index {key!r}")
        k = key[0]
        if k is None:
            if self.type == "vec3":
                raise HomofacError("[..., None] of a vector is not supported in shader code")
            return self  # a scalar broadcasts against vectors by itself
        if isinstance(k, slice):
            start = 0 if k.start is None else k.start
            stop = start + 1 if k.stop is None else k.stop
            if stop - start != 1:
                raise HomofacError(f"only single-component slices are supported in shader code, got {k!r}")
            k = start
        if self.type != "vec3" or not isinstance(k, (int, np.integer)) or not 0 <= k < 3:
            raise HomofacError(f"component {k!r} of a {self.type} value")
        if self.op == "vec3":
            return self.args[int(k)]
        if self.is_const:
            return Expr.const(self.args[0][int(k)], "float")
        return Expr("comp", (self, int(k)), "float")

    # --- operators ----------------------------------------------------------------------------
    def __add__(self, o):
        return _bin("+", self, o)

    def __radd__(self, o):
        return _bin("+", o, self)

    def __sub__(self, o):
        return _bin("-", self, o)

    def __rsub__(self, o):
        return _bin("-", o, self)

    def __mul__(self, o):
        return _bin("*", self, o)

    def __rmul__(self, o):
        return _bin("*", o, self)

    def __truediv__(self, o):
        return _bin("/", self, o, true_division=True)

    def __rtruediv__(self, o):
        return _bin("/", o, self, true_division=True)

    def __pow__(self, o):
        if isinstance(o, (int, np.integer)) and 1 <= o <= 4:
            out = self
            for _ in range(int(o) - 1):
                out = out * self
            return out
        if isinstance(o, (int, float, np.number)) and float(o) == 0.5:
            return NS.sqrt(self)
        raise HomofacError(f"only small integer powers are supported in shader code, got {o!r}")

    def __neg__(self):
        if self.is_const:
            return Expr.const(-np.asarray(self.args[0]) if self.type == "vec3" else -self.args[0], self.type)
        return Expr("un", ("-", self), self.type)

    def __pos__(self):
        return self

    def __lt__(self, o):
        return _cmp("<", self, o)

    def __le__(self, o):
        return _cmp("<=", self, o)

    def __gt__(self, o):
        return _cmp(">", self, o)

    def __ge__(self, o):
        return _cmp(">=", self, o)

    def __and__(self, o):
        return _logic("&&", self, o)

    def __rand__(self, o):
        return _logic("&&", o, self)

    def __or__(self, o):
        return _logic("||", self, o)

    def __ror__(self, o):
        return _logic("||", o, self)

    def __invert__(self):
        if self.type != "bool":
            raise HomofacError("~ of a non-boolean shader value")
        return Expr("un", ("!", self), "bool")

    __hash__ = object.__hash__


_INTERNED: "weakref.WeakValueDictionary[tuple, Expr]" = weakref.WeakValueDictionary()


def _key(a: Any):
    if isinstance(a, Expr):
        return ("e", a.id)
    if isinstance(a, np.ndarray):
        return ("a", a.shape, a.tobytes())
    return ("v", type(a).__name__, a)


def _type_of_value(value: Any) -> str:
    a = np.asarray(value)
    if a.shape == (3,):
        return "vec3"
    if a.shape not in ((), (1,)):
        raise HomofacError(f"a shader constant must be a scalar or 3 values, got shape {a.shape}")
    if a.dtype.kind == "b":
        return "bool"
    if a.dtype.kind in "iu":
        return "int"
    return "float"


def lift(x: Any, like: str | None = None) -> Expr:
    """``x`` as an :class:`Expr`; Python numbers take the type ``like`` (int constants become floats
    next to a float operand)."""
    if isinstance(x, Expr):
        return x
    t = _type_of_value(x)
    if like is not None and t in ("int", "float") and like in ("float", "vec3"):
        t = "float"
    if like == "int" and t == "int":
        t = "int"
    return Expr.const(np.asarray(x).reshape(-1)[0] if t != "vec3" else x, t)


def _cast(a: Expr, target: str) -> Expr:
    if a.type == target:
        return a
    if a.type == "vec3" or target == "vec3":
        raise HomofacError(f"cannot cast {a.type} to {target} in shader code")
    if a.is_const:
        v = a.args[0]
        return Expr.const({"int": int, "float": float, "bool": bool}[target](v), target)
    return Expr("cast", (a,), target)


def _numeric(a: Expr, b: Expr) -> tuple[Expr, Expr, str]:
    """Promote two operands: int -> float next to a float, scalars stay scalars next to vectors."""
    for x in (a, b):
        if x.type == "bool":
            raise HomofacError("arithmetic on a boolean shader value")
    if "vec3" in (a.type, b.type) or "float" in (a.type, b.type):
        a = _cast(a, "float") if a.type == "int" else a
        b = _cast(b, "float") if b.type == "int" else b
        return a, b, "vec3" if "vec3" in (a.type, b.type) else "float"
    return a, b, "int"


def _fold(op: str, x, y):
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return {"+": x + y, "-": x - y, "*": x * y, "/": x / y}[op]


def _bin(op: str, a: Any, b: Any, true_division: bool = False) -> Expr:
    ea = a if isinstance(a, Expr) else None
    eb = b if isinstance(b, Expr) else None
    like = (ea if ea is not None else eb).type
    a, b = lift(a, like), lift(b, like)
    if true_division and a.type == "int" and b.type == "int":
        a, b = _cast(a, "float"), _cast(b, "float")
    a, b, t = _numeric(a, b)
    if a.is_const and b.is_const:
        v = _fold(op, a.args[0], b.args[0])
        return Expr.const(int(v) if t == "int" else v, t)
    # algebraic identities that keep the generated code short (exact in IEEE arithmetic)
    if op == "*" and b.is_const and (b.args[0] == 1 or b.args[0] == (1.0, 1.0, 1.0)) and a.type == t:
        return a
    if op == "*" and a.is_const and (a.args[0] == 1 or a.args[0] == (1.0, 1.0, 1.0)) and b.type == t:
        return b
    if op == "*" and b.is_const and b.type != "vec3" and b.args[0] == 1:
        return a if a.type == t else Expr("bin", (op, a, b), t)
    if op == "*" and a.is_const and a.type != "vec3" and a.args[0] == 1:
        return b if b.type == t else Expr("bin", (op, a, b), t)
    if op in "+-" and b.is_const and b.type != "vec3" and b.args[0] == 0 and a.type == t:
        return a
    return Expr("bin", (op, a, b), t)


def _cmp(op: str, a: Any, b: Any) -> Expr:
    like = (a if isinstance(a, Expr) else b).type
    a, b = lift(a, like), lift(b, like)
    a, b, t = _numeric(a, b)
    if t == "vec3":
        raise HomofacError("comparisons of vectors are not supported in shader code")
    return Expr("bin", (op, a, b), "bool")


def _logic(op: str, a: Any, b: Any) -> Expr:
    a, b = lift(a, "bool"), lift(b, "bool")
    if a.type != "bool" or b.type != "bool":
        raise HomofacError(f"{op} needs boolean shader values, got {a.type} and {b.type}")
    return Expr("bin", (op, a, b), "bool")


def _same(a: Expr, b: Expr) -> tuple[Expr, Expr, str]:
    """Operands of a function whose arguments must share one type (select, max, min, clamp)."""
    if a.type == b.type:
        return a, b, a.type
    a, b, t = _numeric(a, b)
    if t == "vec3":
        a = _splat(a) if a.type != "vec3" else a
        b = _splat(b) if b.type != "vec3" else b
    return a, b, t


def _splat(s: Expr) -> Expr:
    if s.is_const:
        return Expr.const((s.args[0],) * 3, "vec3")
    return Expr("vec3", (s, s, s), "vec3")


def _call(fn: str, *args: Expr, type: str) -> Expr:
    return Expr("call", (fn, *args), type)


class Table:
    """A constant (N, 3) table in shader code, indexed by an int expression: ``table[i]`` -> vec3."""

    def __init__(self, values: np.ndarray):
        v = np.asarray(values, np.float64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise HomofacError(f"shader tables must have shape (N, 3), got {v.shape}")
        self.values = v
        digest = hashlib.sha1(np.ascontiguousarray(v).tobytes()).hexdigest()[:8]
        self.node = Expr("table", (f"HF_TABLE_{digest}", v), "vec3")

    def __getitem__(self, i) -> Expr:
        if not isinstance(i, Expr) or i.type != "int":
            raise HomofacError("a shader table is indexed by an int expression")
        return Expr("index", (self.node, i), "vec3")


class Namespace:
    """The array functions of :mod:`homofac.sphere` and the records, on :class:`Expr` values."""

    float32 = np.float32
    float64 = np.float64
    int32 = np.int32
    bool_ = np.bool_
    pi = np.pi

    @staticmethod
    def asarray(x, dtype=None):
        if isinstance(x, Expr):
            return x if dtype is None else x.astype(dtype)
        a = np.asarray(x)
        if a.ndim == 2:
            return Table(a)
        e = Expr.const(a, _type_of_value(a))
        return e if dtype is None or e.type == "vec3" else e.astype(dtype)

    @staticmethod
    def shape(x) -> tuple:
        return ()

    @staticmethod
    def full(shape, value, dtype=None):
        if tuple(np.shape(shape) and shape) not in ((),):
            raise HomofacError("shader code is scalar per pixel: full() takes shape ()")
        e = Expr.const(value)
        return e if dtype is None else e.astype(dtype)

    @staticmethod
    def where(cond, a, b):
        cond = lift(cond, "bool")
        if cond.type != "bool":
            raise HomofacError("where() needs a boolean condition in shader code")
        like = (a if isinstance(a, Expr) else b if isinstance(b, Expr) else cond).type
        like = like if like != "bool" else None
        a, b = lift(a, like), lift(b, like)
        a, b, t = _same(a, b)
        if cond.is_const:
            return a if cond.args[0] else b
        return Expr("select", (cond, a, b), t)

    @staticmethod
    def maximum(a, b):
        return _minmax("max", a, b)

    @staticmethod
    def minimum(a, b):
        return _minmax("min", a, b)

    @staticmethod
    def abs(a):
        a = lift(a)
        return _call("abs", a, type=a.type)

    @staticmethod
    def sqrt(a):
        a = _cast(lift(a, "float"), "float") if lift(a).type == "int" else lift(a)
        return _call("sqrt", a, type=a.type)

    @staticmethod
    def floor(a):
        a = lift(a, "float")
        return _call("floor", a, type=a.type)

    @staticmethod
    def clip(a, lo, hi):
        a = lift(a)
        like = a.type
        lo, hi = lift(lo, like), lift(hi, like)
        a, lo, t = _same(a, lo)
        a, hi, t = _same(a, hi)
        if lo.type != t:
            lo = _same(lo, a)[0]
        return _call("clamp", a, lo, hi, type=t)

    @staticmethod
    def sum(x, axis=-1, keepdims=False):
        if axis not in (-1,) or not isinstance(x, Expr) or x.type != "vec3":
            raise HomofacError("shader code sums vectors over their last axis only")
        if x.op == "bin" and x.args[0] == "*" and x.args[1].type == "vec3" and x.args[2].type == "vec3":
            return _call("dot", x.args[1], x.args[2], type="float")
        return x[..., 0] + x[..., 1] + x[..., 2]

    @staticmethod
    def stack(items, axis=-1):
        if axis != -1 or len(items) != 3:
            raise HomofacError("shader code stacks exactly three scalars into a vec3")
        xs = [lift(i, "float") for i in items]
        xs = [_cast(x, "float") for x in xs]
        if any(x.type != "float" for x in xs):
            raise HomofacError("stack() of non-scalar shader values")
        if all(x.is_const for x in xs):
            return Expr.const([x.args[0] for x in xs], "vec3")
        return Expr("vec3", tuple(xs), "vec3")

    @staticmethod
    def cross(a, b):
        return _call("cross", lift(a, "vec3"), lift(b, "vec3"), type="vec3")

    @staticmethod
    def arctan2(y, x):
        y, x = lift(y, "float"), lift(x, "float")
        return _call("atan2", y, x, type="float")


def _minmax(fn: str, a, b) -> Expr:
    like = (a if isinstance(a, Expr) else b).type
    a, b = lift(a, like), lift(b, like)
    a, b, t = _same(a, b)
    if a.is_const and b.is_const and t != "vec3":
        return Expr.const((max if fn == "max" else min)(a.args[0], b.args[0]), t)
    return _call(fn, a, b, type=t)


NS = Namespace()
Expr.__homofac_namespace__ = NS


def vec3_input(name: str) -> Expr:
    """A symbolic ``vec3`` function argument."""
    return Expr.input(name, "vec3")


def float_input(name: str) -> Expr:
    """A symbolic ``float`` function argument."""
    return Expr.input(name, "float")


__all__ = ["Expr", "NS", "Namespace", "TYPES", "Table", "float_input", "lift", "vec3_input"]
