"""The one validation mechanism: strict pydantic option models and one-line errors (issue 7).

Every layer declares the options it reads as a pydantic model derived from :class:`Options` (unknown
keys are errors, values are not silently coerced), the way a Mitsuba plugin declares its parameters.
The YAML config of :mod:`homofac.app.config` is assembled from these same models, and the Python API
validates its keyword dicts through them with :func:`validate`, so the CLI and ``hf.fit.factorize``
refuse exactly the same inputs with exactly the same message::

    validate(SamplingOptions, {"kind": "texels", "sise": 8}, "sampling")
    HomofacError: sampling: unknown key sise (did you mean size?)

Limits (ranges, allowed names) live in these models and nowhere else.
"""

from __future__ import annotations

import difflib
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from .errors import HomofacError

M = TypeVar("M", bound=BaseModel)


class Options(BaseModel):
    """Base of every option model: unknown keys are errors, strings are not parsed into numbers.

    ``strict`` keeps YAML's types honest (``"small"`` is not a tolerance, ``1.5`` is not an integer);
    integers are accepted where a float is expected (JSON and YAML write 1 for 1.0).
    """

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models inside an annotation (``Optional[M]``, ``list[M]``, ``A | B``, ``Annotated``)."""
    out, stack = [], [annotation]
    while stack:
        a = stack.pop()
        if isinstance(a, type) and issubclass(a, BaseModel):
            out.append(a)
            continue
        stack.extend(getattr(a, "__args__", ()) or ())
        origin = getattr(a, "__origin__", None)
        if origin is not None and getattr(a, "__metadata__", None):
            stack.append(origin)
    return out


def _resolve(model: type[BaseModel] | None, loc: tuple) -> tuple[tuple, list[str], dict[str, str]]:
    """``loc`` without the tags pydantic inserts for tagged unions, the keys known where it ends, and the
    keys moved elsewhere there (a model's ``MOVED``: old key -> its place).

    A location is a path of field names and list indices; a tagged union (``solver`` options chosen
    by ``method``) adds its tag value as an extra part, which is not a key the user wrote.
    """
    clean: list = []
    current: list[type[BaseModel]] = [model] if model is not None else []
    for i, part in enumerate(loc):
        if isinstance(part, int):
            clean.append(part)
            continue
        if not current and clean:
            continue  # below a leaf field: pydantic names the union member it tried ("float"), not a key
        tagged = [m for m in current if getattr(m, "TAG", None) == part]
        if tagged and len(current) > 1:
            current = tagged  # the union member pydantic tried: not a key
            continue
        clean.append(part)
        if i == len(loc) - 1:
            break
        nxt: list[type[BaseModel]] = []
        for m in current:
            info = m.model_fields.get(part)
            if info is not None:
                nxt.extend(_models_in(info.annotation))
        current = nxt
    known: list[str] = []
    moved: dict[str, str] = {}
    for m in current:
        known.extend(k for k in m.model_fields if k not in known)
        moved.update(getattr(m, "MOVED", None) or {})
    return tuple(clean), known, moved


def _key_text(part: Any) -> str:
    """A key as it appears in a message: itself, or quoted (``repr``) when it is empty, has surrounding
    spaces or holds a non-printable character (a newline in a key must not break the one-line error)."""
    s = str(part)
    return s if s and s.isprintable() and s.strip() == s else _short(s)


def _short(value: Any, limit: int = 60) -> str:
    s = repr(value)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def format_error(e: ValidationError, where: str, model: type[BaseModel] | None = None) -> str:
    """One line naming the first problem of a pydantic ``ValidationError`` and the key it is at."""
    errors = e.errors()
    err = errors[0]
    raw = tuple(x for x in err["loc"] if not (isinstance(x, str) and x.startswith("function-")))
    loc, known, moved = _resolve(model, raw)
    key = ".".join(_key_text(x) for x in loc)
    full = f"{where}.{key}" if where and key else (where or key)
    prefix = f"{full}: " if full else ""
    more = f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else ""
    if err["type"] == "extra_forbidden":
        name = str(loc[-1]) if loc else ""
        if name in moved:
            section, _, rest = moved[name].partition(".")
            return f"{name} is an {section} key: write it under {section}: ({moved[name]}){more}"
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]}?)" if close else (f"; known keys: {', '.join(known)}" if known else "")
        name = _key_text(name)
        parent = ".".join(_key_text(x) for x in loc[:-1])
        at = f"{where}.{parent}" if where and parent else (where or parent or "config")
        return f"{at}: unknown key {name}{hint}{more}"
    if err["type"] == "missing":
        return f"{full or 'a value'}: missing{more}"
    if err["type"] == "union_tag_invalid":
        ctx = err.get("ctx", {})
        return f"{full}: unknown {ctx.get('tag')!r}; expected one of {ctx.get('expected_tags')}{more}"
    msg = err["msg"]
    if err["type"] == "literal_error" and isinstance(err.get("input"), str):
        options = [o.strip().strip("'") for o in str(err.get("ctx", {}).get("expected", "")).replace(" or ", ", ").split(",")]
        close = difflib.get_close_matches(err["input"], options, n=1, cutoff=0.6)
        if close:
            msg += f" (did you mean {close[0]}?)"
    for noise in ("Value error, ", "Assertion failed, "):
        if msg.startswith(noise):
            msg = msg[len(noise):]
    got = "" if "got " in msg else f" (got {_short(err.get('input'))})"
    return f"{prefix}{msg}{got}{more}"


def validate(model: type[M], data: Any, where: str = "") -> M:
    """``model`` from ``data`` (an instance of ``model``, a mapping, or None for all defaults).

    Raises :class:`HomofacError` with one line naming the key (``where`` is its prefix, e.g.
    ``sampling``): unknown keys get a "did you mean", wrong types and ranges the field and the value.
    """
    if isinstance(data, model):
        return data
    if data is None:
        data = {}
    if isinstance(data, BaseModel):
        data = data.model_dump()
    if not isinstance(data, dict):
        raise HomofacError(f"{where or 'options'}: expected a mapping of keys, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise HomofacError(format_error(e, where, model)) from None
    except RecursionError:
        raise HomofacError(f"{where or 'options'}: nested too deeply") from None


__all__ = ["Options", "format_error", "validate"]
