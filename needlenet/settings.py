"""Reading ``NAME=VALUE`` settings given as text (``synth --param``, ``track --param``,
``train --param``): one reading for the simulator, the trackers and the training recipe.

``parse_value`` guesses a type from the text alone (for settings without a typed default);
``convert_setting`` reads the text as the type of the setting's field and refuses anything
else with a ValueError that names the setting, the value given and what is expected.
"""

from __future__ import annotations

import math
import re

__all__ = ["parse_value", "convert_setting", "accepts_none"]

_NONE = ("none", "null")
_TRUE = ("true", "1", "yes")
_FALSE = ("false", "0", "no")
_SCALARS = {"bool": False, "int": 0, "float": 0.0, "str": ""}


def parse_value(text: str):
    """A setting's text as None, a boolean, an integer, a float or (otherwise) the text."""
    text = text.strip()
    low = text.lower()
    if low in _NONE:
        return None
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return text


def _type_names(annotation) -> list[str]:
    """The alternatives of a field's annotation (a string under ``from __future__ import
    annotations``, or a type) as names: ``"float | None"`` -> ``["float", "None"]``."""
    if annotation is None:
        return []
    text = annotation if isinstance(annotation, str) else \
        getattr(annotation, "__name__", None) if isinstance(annotation, type) else str(annotation)
    text = re.sub(r"\btyping\.", "", text or "")
    match = re.fullmatch(r"\s*Optional\[(.*)\]\s*", text)
    if match:
        return [*_type_names(match.group(1)), "None"]
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(text):  # split on the | outside brackets
        depth += ch == "["
        depth -= ch == "]"
        if ch == "|" and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip().replace("NoneType", "None") for p in parts if p.strip()]


def accepts_none(annotation) -> bool:
    """Whether a field annotated ``annotation`` may hold None (``X | None``, ``Optional[X]``)."""
    return "None" in _type_names(annotation)


def _example(annotation):
    """A value of the one scalar type a None-default field is annotated with (``float | None``
    -> 0.0), or None where the annotation names no single scalar type."""
    names = [n for n in _type_names(annotation) if n != "None"]
    return _SCALARS.get(names[0]) if len(names) == 1 else None


def _tuple_arity(annotation) -> int | None:
    """How many items a tuple annotation fixes: ``tuple[float, float]`` -> 2, ``tuple[float,
    ...]`` -> 0 (any number), anything else (or no tuple among the alternatives) -> None."""
    for alt in _type_names(annotation):
        match = re.fullmatch(r"(?:tuple|Tuple)\[(.*)\]", alt)
        if match:
            args = [a.strip() for a in match.group(1).split(",")]
            return 0 if "..." in args else len(args)
    return None


def _expected(default) -> str:
    if isinstance(default, bool):
        return "true or false (or 1/0, yes/no)"
    if isinstance(default, int):
        return "an integer"
    if isinstance(default, float):
        return "a finite number"
    if isinstance(default, tuple):
        return "comma-separated values"
    return "text"


def convert_setting(name: str, text: str, default, annotation=None):
    """``text`` as a value of the type of ``default`` (the field's default value): the one
    reading of ``NAME=VALUE`` settings, for ``track --param`` and ``train --param``.

    ``none`` (or ``null``) is None only where the field may hold None: its default is None or
    ``annotation`` (the field's type, optional) admits None. Booleans are true/false, 1/0 or
    yes/no; integers whole numbers; floats finite numbers; tuples comma-separated values, each
    read as the default's element. A field whose default is None is read as the scalar type
    of its annotation when it names one, else by :func:`parse_value` (a number still finite).
    Anything else raises ValueError naming the setting, the value and what is expected."""
    low = text.strip().lower()
    if low in _NONE:
        if default is None or accepts_none(annotation):
            return None
        raise ValueError(f"parameter {name}: expected {_expected(default)}, got {text!r}: "
                         f"{name} cannot be none")
    if default is None:
        example = _example(annotation)
        if example is not None:
            return convert_setting(name, text, example)
        arity = _tuple_arity(annotation)
        if arity is not None:  # ``tuple[float, float] | None``: read as that tuple
            return convert_setting(name, text, (0.0,) * max(arity, 1), annotation)
        value = parse_value(text)
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"parameter {name}: expected a finite number, got {text!r}")
        return value
    if isinstance(default, bool):
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
        raise ValueError(f"parameter {name}: expected true or false (or 1/0, yes/no), "
                         f"got {text!r}")
    if isinstance(default, int):
        try:
            return int(text)
        except ValueError:
            pass
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"parameter {name}: expected a number (an integer), "
                             f"got {text!r}") from None
        if not value.is_integer():
            raise ValueError(f"parameter {name}: expected an integer, got {text!r}")
        return int(value)
    if isinstance(default, float):
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"parameter {name}: expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise ValueError(f"parameter {name}: expected a finite number, got {text!r}")
        return value
    if isinstance(default, tuple):
        items = [t for t in text.split(",") if t.strip()]
        if not items:
            raise ValueError(f"parameter {name}: expected comma-separated values, got {text!r}")
        arity = _tuple_arity(annotation)
        if arity and len(items) != arity:  # tuple[float, float]: exactly two
            raise ValueError(f"parameter {name}: expected {arity} comma-separated values, got "
                             f"{text!r}")
        same = len(items) == len(default)
        values = []
        for i, item in enumerate(items):
            element = default[i] if same else default[0] if default else 0.0
            try:
                values.append(convert_setting(name, item.strip(), element))
            except ValueError as exc:  # the whole value too
                raise ValueError(f"{exc} (item {i + 1} of {text!r})") from None
        return tuple(values)
    if isinstance(default, str):
        return text
    raise ValueError(f"parameter {name} ({type(default).__name__}) cannot be set as text; "
                     f"set its fields instead ({name}.FIELD=VALUE)")
