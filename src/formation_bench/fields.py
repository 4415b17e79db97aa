"""Configuration fields declared once: default, allowed values and a one-line doc.

A config dataclass declares each setting with :func:`setting`, e.g.::

    population_size: int = setting(30, low=2, doc="N, ideas per iteration")

and calls :func:`validate_fields` from ``__post_init__`` (or inherits
:class:`Validated`): every declared field is checked against its declaration
and normalised (integers to ``int``, reals to ``float``, enum names to
members) with one message shape, "<Class>.<field> must be ..., got <value>".
:func:`describe_fields` lists the declarations for the command line, and
:func:`kernel_settings_class` turns the fields marked ``kernel=True`` into the
namedtuple a compiled kernel reads by name, so the kernel's settings cannot
drift from the dataclass. A setting worth tuning also declares the range a tuner searches
(:class:`Search`), which :func:`search_text` puts in words.

Neutral on purpose: this module imports nothing from the optimisers, the MPC
harness or the benchmarks, so all of them can declare their settings with it.
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import math
from collections.abc import Callable, Iterable
from typing import Any, NamedTuple, TypeVar

import numpy as np

EnumT = TypeVar("EnumT", bound=enum.Enum)

Limit = int | float | str | Callable[[Any], Any] | None
"""A range end: a number, the name of an earlier field, or ``f(obj) -> number``."""

METADATA_KEY = "formation_bench.setting"


# --- the single-value checks (also used directly, e.g. by run-time arguments) ------------------


def member_text(member: enum.Enum) -> str:
    """How an enum member is written in a value, a listing and an error: its text value
    (``k-nearest``), or its name in lower case for a numbered member (``rand_1_bin``)."""
    return member.value if isinstance(member.value, str) else member.name.lower()


def coerce_enum(owner: str, name: str, enum_type: type[EnumT], value: object) -> EnumT:
    """``value`` as a member of ``enum_type``.

    Accepts a member, its name in any case with '-' for '_' (the CLI passes
    strings, e.g. ``replacement_map=tent``), or its value.
    """
    if isinstance(value, enum_type):
        return value
    if isinstance(value, str):
        key = value.strip().upper().replace("-", "_")
        if key in enum_type.__members__:
            return enum_type[key]
    if not isinstance(value, bool):
        try:
            return enum_type(value)
        except (ValueError, TypeError):
            pass
    allowed = ", ".join(member_text(m) for m in enum_type)
    raise ValueError(f"{owner}.{name} must be one of {allowed}, got {value!r}")


def int_range_text(low: int, high: int | str | None) -> str:
    """How :func:`check_int` words its range: ``>= low`` or ``in [low, high]``."""
    return f">= {low}" if high is None else f"in [{low}, {high}]"


def check_int(owner: str, name: str, value: object, low: int, high: int | None = None) -> int:
    """``value`` if it is an integer (not a bool) in ``[low, high]``, else ValueError."""
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
    if ok and low <= value and (high is None or value <= high):  # type: ignore[operator]
        return int(value)  # type: ignore[arg-type]
    raise ValueError(
        f"{owner}.{name} must be an integer {int_range_text(low, high)}, got {value!r}"
    )


def real_range_text(
    low: float | str, high: float | str, low_open: bool = False, high_open: bool = False
) -> str:
    """How :func:`check_real` words its interval, e.g. ``(0.0, inf)`` or ``[0.0, 1.0]``."""
    closed_high = not high_open and not (isinstance(high, float | int) and math.isinf(high))
    return f"{'(' if low_open else '['}{low}, {high}{']' if closed_high else ')'}"


def check_real(
    owner: str,
    name: str,
    value: object,
    low: float,
    high: float = math.inf,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """``value`` as a float if finite and in ``[low, high]`` (open ends as flagged)."""
    ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )
    if ok:
        v = float(value)  # type: ignore[arg-type]
        above = v > low if low_open else v >= low
        below = v < high if high_open else v <= high
        if math.isfinite(v) and above and below:
            return v
    interval = real_range_text(low, high, low_open, high_open)
    raise ValueError(f"{owner}.{name} must be a finite number in {interval}, got {value!r}")


def check_bool(owner: str, name: str, value: object) -> bool:
    """``value`` if it is a bool, else ValueError."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    raise ValueError(f"{owner}.{name} must be True or False, got {value!r}")


def check_choice(owner: str, name: str, value: object, choices: Iterable[str]) -> str:
    """``value`` if it is one of the strings ``choices``, else ValueError."""
    allowed = tuple(choices)
    if isinstance(value, str) and value in allowed:
        return value
    raise ValueError(f"{owner}.{name} must be one of {', '.join(allowed)}, got {value!r}")


# --- declarations ------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Search:
    """What is worth searching for a setting, beside what is valid (pymoo's ``bounds`` beside
    its ``strict``): a tuner searches only settings declared with one.

    For an ``int`` or ``real`` setting, ``low`` and ``high`` are required and, like the
    validity limits, may name an earlier field or be ``f(obj) -> number``; they are resolved
    against the configuration being tuned when the search space is built, and the resolved
    range must lie inside the valid one. For a ``bool``, ``enum`` or ``choice`` setting,
    ``choices`` (None: every allowed value) lists the values searched, as they are written on
    the command line.
    """

    low: Limit = None
    """Smallest value searched (int and real settings)."""
    high: Limit = None
    """Largest value searched (int and real settings)."""
    log: bool = False
    """Search on a log scale (both ends then must be > 0)."""
    choices: tuple[Any, ...] | None = None
    """The values searched (bool, enum and choice settings); None: every allowed value."""


@dataclasses.dataclass(frozen=True)
class Setting:
    """What :func:`setting` records in a field's metadata."""

    kind: str
    """``int``, ``real``, ``bool``, ``enum``, ``choice`` or ``custom``."""
    doc: str
    """One line: what the setting is."""
    low: Limit = None
    high: Limit = None
    low_open: bool = False
    high_open: bool = False
    optional: bool = False
    """None is allowed (and kept) besides the declared values."""
    enum_type: type[enum.Enum] | None = None
    choices: tuple[str, ...] | Callable[[], Iterable[str]] = ()
    """Allowed strings of a ``choice``; a callable is asked at validation (a registry)."""
    check: Callable[[str, str, Any], Any] | None = None
    """``check(owner, name, value) -> value`` for a ``custom`` kind (None: checked elsewhere)."""
    allowed: str = ""
    """The allowed values in words, for a ``custom`` kind."""
    kernel: bool = False
    """The compiled kernels read this field (see :func:`kernel_settings_class`)."""
    search: Search | None = None
    """What a tuner searches (None: the setting is not tuned)."""


def setting(
    default: Any,
    *,
    doc: str,
    low: Limit = None,
    high: Limit = None,
    low_open: bool = False,
    high_open: bool = False,
    kind: type | None = None,
    optional: bool = False,
    choices: tuple[str, ...] | Callable[[], Iterable[str]] = (),
    check: Callable[[str, str, Any], Any] | None = None,
    allowed: str = "",
    kernel: bool = False,
    search: Search | None = None,
) -> Any:
    """A dataclass field with its default, allowed values and one-line doc.

    The kind follows from ``kind`` if given, else from the default's type:
    ``bool``, ``int`` (closed range ``[low, high]``, ``low`` required), ``float``
    (finite, ``low``/``high`` with open ends as flagged; missing ends are
    infinite), an :class:`enum.Enum` (coerced from names like ``coerce_enum``),
    ``str`` with ``choices``, or anything with a ``check`` callable or an
    ``allowed`` text (``custom``: tuples and other structured values, checked by
    ``check`` or by the class's own code). ``high`` (and ``low``) may name an
    earlier field (``high="population_size"``) or be ``f(obj) -> limit``.
    ``optional`` also allows None. ``search`` declares the range a tuner searches
    (:class:`Search`); a setting without one is not tuned.
    """
    spec = _make_setting(
        default, doc, low, high, low_open, high_open, kind, optional, choices, check, allowed,
        kernel,
    )  # fmt: skip
    if search is not None:
        spec = dataclasses.replace(spec, search=_checked_search(spec, search))
    return dataclasses.field(default=default, metadata={METADATA_KEY: spec})


def _make_setting(
    default: Any,
    doc: str,
    low: Limit,
    high: Limit,
    low_open: bool,
    high_open: bool,
    kind: type | None,
    optional: bool,
    choices: tuple[str, ...] | Callable[[], Iterable[str]],
    check: Callable[[str, str, Any], Any] | None,
    allowed: str,
    kernel: bool,
) -> Setting:
    if not doc or "\n" in doc:
        raise ValueError(f"a setting needs a one-line doc, got {doc!r}")
    kind = type(default) if kind is None else kind
    enum_type = None
    if check is not None or allowed:
        name = "custom"
    elif kind is bool:
        name = "bool"
    elif isinstance(kind, type) and issubclass(kind, enum.Enum):
        name, enum_type = "enum", kind
    elif kind is int:
        if not isinstance(low, int | str) and not callable(low):
            raise ValueError("an integer setting needs low")
        name = "int"
    elif kind is float:
        name = "real"
    elif kind is str and choices:
        name = "choice"
    else:
        raise TypeError(f"cannot declare a setting of kind {kind!r} without check or allowed")
    return Setting(
        name, doc, low, high, low_open, high_open, optional, enum_type, choices, check, allowed,
        kernel,
    )  # fmt: skip


def _checked_search(spec: Setting, search: Search) -> Search:
    if not isinstance(search, Search):
        raise TypeError(f"search must be a formation_bench.fields.Search, got {search!r}")
    if spec.kind in ("int", "real"):
        if search.low is None or search.high is None or search.choices is not None:
            raise ValueError(f"the search of an {spec.kind} setting needs low and high only")
        numeric = all(isinstance(v, int | float) for v in (search.low, search.high))
        if numeric and not search.low < search.high:  # type: ignore[operator]
            raise ValueError(f"search low must be below high, got {search.low}, {search.high}")
        if search.log and numeric and search.low <= 0:  # type: ignore[operator]
            raise ValueError(f"a log-scale search needs low > 0, got {search.low}")
    elif spec.kind in ("bool", "enum", "choice"):
        if search.low is not None or search.high is not None or search.log:
            raise ValueError(f"the search of a {spec.kind} setting takes choices only")
    else:
        raise ValueError(f"a {spec.kind} setting cannot be searched")
    return search


def declared(field: dataclasses.Field) -> Setting | None:
    """The :class:`Setting` of a dataclass field, or None if it was not declared with one."""
    return field.metadata.get(METADATA_KEY)


def _limit(obj: Any, limit: Limit) -> Any:
    if isinstance(limit, str):
        return getattr(obj, limit)
    if callable(limit):
        return limit(obj)
    return limit


def check_value(obj: Any, owner: str, name: str, spec: Setting, value: Any) -> Any:
    """``value`` checked and normalised against ``spec`` (limits read from ``obj``)."""
    if spec.optional and value is None:
        return None
    if spec.kind == "bool":
        return check_bool(owner, name, value)
    if spec.kind == "enum":
        assert spec.enum_type is not None
        return coerce_enum(owner, name, spec.enum_type, value)
    if spec.kind == "int":
        return check_int(owner, name, value, _limit(obj, spec.low), _limit(obj, spec.high))
    if spec.kind == "real":
        low, high = _limit(obj, spec.low), _limit(obj, spec.high)
        return check_real(
            owner, name, value, -math.inf if low is None else low,
            math.inf if high is None else high, low_open=spec.low_open, high_open=spec.high_open,
        )  # fmt: skip
    if spec.kind == "choice":
        choices = spec.choices() if callable(spec.choices) else spec.choices
        return check_choice(owner, name, value, choices)
    return value if spec.check is None else spec.check(owner, name, value)


def validate_fields(obj: Any) -> None:
    """Check and normalise every declared field of the dataclass instance ``obj``, in order.

    Raises ValueError naming ``Class.field`` for the first bad value; fields
    are written back with ``object.__setattr__`` so frozen dataclasses work.
    Limits naming another field read its already normalised value.
    """
    owner = type(obj).__name__
    for field in dataclasses.fields(obj):
        spec = declared(field)
        if spec is None:
            continue
        value = getattr(obj, field.name)
        normal = check_value(obj, owner, field.name, spec, value)
        if normal is not value:
            object.__setattr__(obj, field.name, normal)


class Validated:
    """Mixin for config dataclasses whose ``__post_init__`` is :func:`validate_fields` alone."""

    def __post_init__(self) -> None:
        validate_fields(self)


# --- description -------------------------------------------------------------------------------


class FieldInfo(NamedTuple):
    """One declared field, as ``formation-bench list --fields`` shows it."""

    name: str
    type: str
    """The annotation as written, e.g. ``int`` or ``ChaoticMap``."""
    default: Any
    """The declared default."""
    allowed: str
    """The allowed values in words, e.g. ``in [1, population_size]`` or ``(0.0, inf)``."""
    doc: str
    value: Any
    """The value of the described instance (the default when a class is described)."""
    search: str = "not tuned"
    """What a tuner searches, in words (:func:`search_text`), e.g. ``searched: [4, 100] log``."""


def _limit_text(limit: Limit, fallback: str) -> str:
    if limit is None:
        return fallback
    if isinstance(limit, str):
        return limit
    if callable(limit):
        return getattr(limit, "__doc__", None) or fallback
    return str(limit)


def allowed_text(spec: Setting) -> str:
    """The allowed values of ``spec`` in words (the wording of the error messages)."""
    if spec.kind == "bool":
        text = "True or False"
    elif spec.kind == "enum":
        assert spec.enum_type is not None
        text = "one of " + ", ".join(member_text(m) for m in spec.enum_type)
    elif spec.kind == "int":
        low = _limit_text(spec.low, "")
        text = (
            f"integer >= {low}" if spec.high is None
            else f"integer in [{low}, {_limit_text(spec.high, '')}]"
        )  # fmt: skip
    elif spec.kind == "real":
        low = -math.inf if spec.low is None else spec.low
        high = math.inf if spec.high is None else spec.high
        text = "finite number in " + real_range_text(
            _limit_text(low, "-inf") if not isinstance(low, float | int) else low,
            _limit_text(high, "inf") if not isinstance(high, float | int) else high,
            spec.low_open,
            spec.high_open,
        )
    elif spec.kind == "choice":
        choices = spec.choices() if callable(spec.choices) else spec.choices
        text = "one of " + ", ".join(choices)
    else:
        text = spec.allowed or "see the documentation"
    return f"{text}, or None" if spec.optional else text


def searched_values(spec: Setting) -> tuple[Any, ...]:
    """The values a tuner tries of a bool, enum or choice setting, as the command line writes
    them (its search's ``choices``, else every allowed value)."""
    assert spec.search is not None and spec.kind in ("bool", "enum", "choice")
    if spec.search.choices is not None:
        return tuple(spec.search.choices)
    if spec.kind == "bool":
        return (False, True)
    if spec.kind == "enum":
        assert spec.enum_type is not None
        return tuple(member_text(m) for m in spec.enum_type)
    return tuple(spec.choices() if callable(spec.choices) else spec.choices)


def search_bounds(obj: Any, spec: Setting) -> tuple[Any, Any]:
    """``(low, high)`` of an int or real setting's search, limits naming a field or computed
    from one read from ``obj`` (the configuration being tuned)."""
    assert spec.search is not None and spec.kind in ("int", "real")
    return _limit(obj, spec.search.low), _limit(obj, spec.search.high)


def search_text(spec: Setting) -> str:
    """What a tuner searches of ``spec`` in words: ``searched: [low, high]`` (``log`` on a
    log scale), ``searched: clip, reflect, resample``, or ``not tuned``."""
    search = spec.search
    if search is None:
        return "not tuned"
    if spec.kind in ("int", "real"):
        low, high = (_limit_text(end, "") for end in (search.low, search.high))
        return f"searched: [{low}, {high}]" + (" log" if search.log else "")
    return "searched: " + ", ".join(str(v) for v in searched_values(spec))


def describe_fields(obj_or_class: Any) -> list[FieldInfo]:
    """The declared fields of a config dataclass (class or instance), in declaration order.

    Fields not declared with :func:`setting` are left out.
    """
    is_instance = not isinstance(obj_or_class, type)
    out = []
    for field in dataclasses.fields(obj_or_class):
        spec = declared(field)
        if spec is None:
            continue
        value = getattr(obj_or_class, field.name) if is_instance else field.default
        type_text = (
            field.type
            if isinstance(field.type, str)
            else getattr(field.type, "__name__", str(field.type))
        )
        allowed, search = allowed_text(spec), search_text(spec)
        out.append(
            FieldInfo(field.name, type_text, field.default, allowed, spec.doc, value, search)
        )
    return out


# --- compiled-kernel settings ------------------------------------------------------------------


def kernel_field_names(config: type) -> tuple[str, ...]:
    """The fields of ``config`` declared with ``kernel=True``, in declaration order."""
    return tuple(
        f.name for f in dataclasses.fields(config) if (spec := declared(f)) and spec.kernel
    )


def kernel_settings_class(
    name: str, module: str, config: type, per_solve: tuple[str, ...], doc: str
) -> type[tuple]:
    """A namedtuple class of ``config``'s kernel fields, then the ``per_solve`` values.

    Assign it to the module attribute ``name`` of ``module``: the class is
    pickled (numba's cache) by that module and qualified name.
    """
    cls = collections.namedtuple(name, kernel_field_names(config) + per_solve, module=module)
    cls.__doc__ = doc
    return cls


def kernel_value(value: Any) -> Any:
    """A field value as a kernel reads it: enum members as their integer value."""
    return int(value) if isinstance(value, enum.Enum) else value


def pack_settings(settings_class: type[tuple], obj: Any, **per_solve: Any) -> tuple:
    """The kernel settings of ``obj`` as a *plain* tuple in ``settings_class``'s field order.

    Plain because numba types a plain tuple argument in its C fast path but a
    namedtuple through Python (about 1 us per call); the kernels rebuild the
    namedtuple (``Settings(*packed)``), which costs nothing in compiled code.
    """
    fields = settings_class._fields  # type: ignore[attr-defined]
    count = len(fields) - len(per_solve)
    if per_solve.keys() != set(fields[count:]):  # not the declared-then-per-solve order
        return tuple(
            per_solve[n] if n in per_solve else kernel_value(getattr(obj, n)) for n in fields
        )
    # the declared part is fixed for a (frozen) configuration: read once per instance, outside
    # its dataclass fields (a solve packs its settings again; reading 20 fields took some 5 µs)
    cache = obj.__dict__.setdefault("_declared_kernel_values", {})
    head = cache.get(settings_class)
    if head is None:
        head = cache[settings_class] = tuple(kernel_value(getattr(obj, n)) for n in fields[:count])
    return head + tuple(per_solve[n] for n in fields[count:])
