"""Shading languages: one record each, printing :mod:`homofac.shader.symbolic` graphs as source code.

A :class:`Language` knows its type names, literals, built-in function names, the ternary, casts,
declarations and function syntax; :func:`function` turns a traced formula into a function of that
language. The records are registered in :data:`LANGUAGES` (GLSL 330 core, GLSL ES 3.00, HLSL, MSL,
WGSL); the config's ``output.shaders`` values and the exporter's file names derive from it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import HomofacError
from .symbolic import Expr


def float_literal(x: float, suffix: str = "") -> str:
    """The shortest decimal that reads back as the same float32, always with a '.' or an exponent, and
    ``suffix`` (``f`` in MSL, where an unsuffixed literal is a C++ double)."""
    f = np.float32(x)
    if not np.isfinite(f):
        raise HomofacError(f"non-finite constant {x!r} in shader code")
    s = str(f)
    if "e" in s and "." not in s.split("e")[0]:
        mant, exp = s.split("e")
        s = f"{mant}.0e{exp}"
    elif "." not in s and "e" not in s:
        s += ".0"
    s += suffix
    return f"({s})" if s.startswith("-") else s


def comment(text: str) -> str:
    """``text`` made safe inside a ``//`` or ``/* */`` comment of every language: printable ASCII only (any
    other character, a backslash -- a line continuation -- included, becomes ``_``), no ``*/`` or ``/*``.
    Generated code carries document strings only through this (and validated identifiers)."""
    s = "".join(c if " " <= c <= "~" and c != "\\" else "_" for c in str(text))
    while "*/" in s or "/*" in s:
        s = s.replace("*/", "* /").replace("/*", "/ *")
    return s


@dataclass(frozen=True)
class Language:
    """How one shading language spells the operations of the expression graph."""

    name: str
    title: str
    file: str  # file name of the exported shader
    types: dict  # expression type -> type name
    functions: dict = field(default_factory=dict)  # renamed built-ins (mix -> lerp ...)
    header: str = ""  # first lines of a file (version, precision, includes)
    #: (condition, if true, if false) -> expression
    ternary: Callable[[str, str, str], str] = lambda c, a, b: f"({c} ? {a} : {b})"
    cast: Callable[[str, str], str] = lambda t, a: f"{t}({a})"
    decl: Callable[[str, str, str], str] = lambda t, n, e: f"{t} {n} = {e};"
    signature: Callable[[str, list, str], str] = lambda name, params, ret: (
        f"{ret} {name}({', '.join(f'{t} {n}' for n, t in params)})")
    table: Callable[[str, str, list], str] = lambda t, n, rows: (
        f"const {t} {n}[{len(rows)}] = {t}[{len(rows)}]({', '.join(rows)});")
    #: uniform-free constants at file scope: ``const T name = value;``
    constant: Callable[[str, str, str], str] = lambda t, n, e: f"const {t} {n} = {e};"
    float_suffix: str = ""  # of float literals (MSL: "f", so that no expression is a double)

    def type(self, t: str) -> str:
        return self.types[t]

    def vec3(self, x: str, y: str, z: str) -> str:
        return f"{self.types['vec3']}({x}, {y}, {z})"

    def literal(self, value, t: str) -> str:
        if t == "vec3":
            return self.vec3(*(float_literal(v, self.float_suffix) for v in value))
        if t == "float":
            return float_literal(value, self.float_suffix)
        if t == "int":
            return f"({int(value)})" if int(value) < 0 else str(int(value))
        return "true" if value else "false"

    def call(self, fn: str, args: list[str]) -> str:
        return f"{self.functions.get(fn, fn)}({', '.join(args)})"


def _wgsl_table(t: str, n: str, rows: list) -> str:
    return f"var<private> {n}: array<{t}, {len(rows)}> = array<{t}, {len(rows)}>({', '.join(rows)});"


GLSL = Language(
    "glsl", "GLSL 330 core", "shader.glsl",
    {"float": "float", "int": "int", "bool": "bool", "vec3": "vec3"},
    {"atan2": "atan"}, header="#version 330 core",
)
GLSL_ES = Language(
    "glsl_es", "GLSL ES 3.00", "shader_es.glsl",
    {"float": "float", "int": "int", "bool": "bool", "vec3": "vec3"},
    {"atan2": "atan"},
    header="#version 300 es\nprecision highp float;\nprecision highp int;\nprecision highp sampler2D;",
)
HLSL = Language(
    "hlsl", "HLSL (shader model 5)", "shader.hlsl",
    {"float": "float", "int": "int", "bool": "bool", "vec3": "float3"},
    {"mix": "lerp", "fract": "frac"},
    cast=lambda t, a: f"(({t})({a}))",
    table=lambda t, n, rows: f"static const {t} {n}[{len(rows)}] = {{{', '.join(rows)}}};",
    constant=lambda t, n, e: f"static const {t} {n} = {e};",
)
MSL = Language(
    "msl", "Metal Shading Language 2", "shader.metal",
    {"float": "float", "int": "int", "bool": "bool", "vec3": "float3"},
    {},
    header="#include <metal_stdlib>\nusing namespace metal;",
    table=lambda t, n, rows: f"constant {t} {n}[{len(rows)}] = {{{', '.join(rows)}}};",
    constant=lambda t, n, e: f"constant {t} {n} = {e};",
    float_suffix="f",
)
WGSL = Language(
    "wgsl", "WGSL", "shader.wgsl",
    {"float": "f32", "int": "i32", "bool": "bool", "vec3": "vec3<f32>"},
    {},
    ternary=lambda c, a, b: f"select({b}, {a}, {c})",
    decl=lambda t, n, e: f"let {n}: {t} = {e};",
    signature=lambda name, params, ret: f"fn {name}({', '.join(f'{n}: {t}' for n, t in params)}) -> {ret}",
    table=_wgsl_table,
    constant=lambda t, n, e: f"const {n}: {t} = {e};",
)

#: The registered languages by config name (``output.shaders``).
LANGUAGES: dict[str, Language] = {lang.name: lang for lang in (GLSL, GLSL_ES, HLSL, MSL, WGSL)}


def get(name: str) -> Language:
    """The language registered as ``name`` (one-line error naming the known ones otherwise)."""
    if name not in LANGUAGES:
        raise HomofacError(f"unknown shading language {name!r}; known: {', '.join(LANGUAGES)}")
    return LANGUAGES[name]


# --------------------------------------------------------------------------------------------------
# Printing a graph


def _operands(e: Expr) -> list[Expr]:
    if e.op in ("input", "const", "table"):
        return []
    if e.op in ("bin",):
        return [e.args[1], e.args[2]]
    if e.op == "un":
        return [e.args[1]]
    if e.op == "call":
        return list(e.args[1:])
    if e.op == "comp":
        return [e.args[0]]
    if e.op == "index":
        return [e.args[1]]
    return list(e.args)  # select, vec3, cast


def _order(roots: list[Expr]) -> tuple[list[Expr], dict[int, int]]:
    """Nodes in dependency order (post-order DFS) and how often each is used."""
    order: list[Expr] = []
    uses: dict[int, int] = {}
    seen: set[int] = set()
    stack = [(r, False) for r in reversed(roots)]
    while stack:
        node, done = stack.pop()
        if done:
            order.append(node)
            continue
        if node.id in seen:
            continue
        seen.add(node.id)
        stack.append((node, True))
        for child in reversed(_operands(node)):
            uses[child.id] = uses.get(child.id, 0) + 1
            stack.append((child, False))
    return order, uses


def tables(roots: list[Expr]) -> dict[str, np.ndarray]:
    """The constant tables a graph indexes, by name."""
    order, _ = _order(roots)
    return {e.args[0].args[0]: e.args[0].args[1] for e in order if e.op == "index"}


def table_source(lang: Language, name: str, values: np.ndarray) -> str:
    """File-scope declaration of a constant (N, 3) table."""
    return lang.table(lang.type("vec3"), name, [lang.literal(r, "vec3") for r in values])


def function(lang: Language, name: str, params: list[tuple[str, str]], result: Expr, doc: str = "") -> str:
    """Source of the function ``name(params) -> result`` in ``lang`` (file-scope tables not included).

    Nodes used more than once, every select, every call of a generated ``hf_`` function and every
    expression longer than a line get a local variable; the rest is inlined, fully parenthesised. ``params`` are ``(name, expression type)`` pairs matching the graph's inputs.
    """
    order, uses = _order([result])
    names = {n for n, _ in params}
    for e in order:
        if e.op == "input" and e.args[0] not in names:
            raise HomofacError(f"shader function {name}: input {e.args[0]!r} is not a parameter")
    text: dict[int, str] = {}
    lines: list[str] = []
    count = 0
    for e in order:
        s = _print(lang, e, text)
        if e.op in ("input", "const", "table"):
            text[e.id] = s
            continue
        long = len(s) > 72 or (e.op == "call" and e.args[0].startswith("hf_"))
        if (uses.get(e.id, 0) > 1 or e.op == "select" or long) and e is not result:
            count += 1
            var = f"t{count}"
            lines.append("    " + lang.decl(lang.type(e.type), var, s))
            text[e.id] = var
        else:
            text[e.id] = s
    ret = text[result.id]
    sig = lang.signature(name, [(n, lang.type(t)) for n, t in params], lang.type(result.type))
    note = f"  // {comment(doc)}" if doc else ""
    return sig + " {" + note + "\n" + "".join(line + "\n" for line in lines) + f"    return {ret};\n}}"


def _print(lang: Language, e: Expr, text: dict[int, str]) -> str:
    a = [text[c.id] for c in _operands(e)]
    if e.op == "input":
        return e.args[0]
    if e.op == "const":
        return lang.literal(e.args[0], e.type)
    if e.op == "table":
        return e.args[0]
    if e.op == "bin":
        return f"({a[0]} {e.args[0]} {a[1]})"
    if e.op == "un":
        return f"({e.args[0]}{a[0]})"
    if e.op == "call":
        return lang.call(e.args[0], a)
    if e.op == "select":
        return lang.ternary(a[0], a[1], a[2])
    if e.op == "comp":
        return f"{a[0]}.{'xyz'[e.args[1]]}"
    if e.op == "vec3":
        return lang.vec3(*a)
    if e.op == "cast":
        return lang.cast(lang.type(e.type), a[0])
    if e.op == "index":
        return f"{e.args[0].args[0]}[{a[0]}]"
    raise HomofacError(f"cannot print shader node {e.op}")


__all__ = ["GLSL", "GLSL_ES", "HLSL", "LANGUAGES", "Language", "MSL", "WGSL", "comment", "float_literal", "function", "get",
           "table_source", "tables"]
