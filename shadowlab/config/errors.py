"""Config errors and their messages, and the translation of pydantic validation errors.

Every message has the form ``<where>: <dotted key> <what is wrong and what is
allowed>``, where ``<where>`` is the config file, ``--set`` (the value came from an
override) or ``<built-in default>``. :func:`from_validation_error` turns a pydantic
:class:`~pydantic.ValidationError` of one config table into such a message: the error's
location becomes the dotted key, a ``Literal`` lists its allowed values, and a number's
bounds (``gt``/``ge``/``lt``/``le``) are named through the field's ``wanted`` text, which
:mod:`shadowlab.config.schema` builds from the same bounds it gives pydantic.
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from pathlib import Path
from typing import Any, Sequence

from pydantic import BaseModel, ValidationError

#: ``RunConfig.source`` (and the label in error messages) for the packaged default.
BUILTIN_DEFAULT = "<built-in default>"
#: The label in error messages for values introduced by ``--set`` overrides.
OVERRIDE_LABEL = "--set"


class ConfigError(ValueError):
    """An invalid run or experiment configuration; the message names the file (or
    ``--set``), the dotted key, what is wrong and the allowed values."""


def show(value: Any) -> str:
    """A value as the user wrote it (TOML-ish): lists in brackets, strings quoted."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {show(v)}" for k, v in value.items()) + "}"
    return repr(value)


def type_name(value: Any) -> str:
    """The TOML kind of ``value`` with its article ("an integer", "a table")."""
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int):
        return "an integer"
    if isinstance(value, float):
        return "a float"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, (list, tuple)):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def did_you_mean(word: str, allowed: Sequence[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest allowed word, or ``""``."""
    close = difflib.get_close_matches(word, list(allowed), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def origin(keys: Sequence[str], override_keys: Sequence[str], label: str) -> str:
    """``--set`` when an override set one of ``keys`` exactly or a table holding it,
    else ``label`` (the config file or the built-in default)."""
    for key in keys:
        for ok in override_keys:
            if key == ok or key.startswith(ok + "."):
                return OVERRIDE_LABEL
    return label


@dataclasses.dataclass
class Context:
    """Where values come from: the config label, its folder, the overridden keys."""

    label: str
    base_dir: Path
    override_keys: list[str]

    def where(self, *keys: str) -> str:
        """The label for a value at one of the dotted ``keys`` (see :func:`origin`)."""
        return origin(keys, self.override_keys, self.label)

    def error(self, key: str, message: str, *also: str) -> ConfigError:
        """A ConfigError ``<where>: <key> <message>``."""
        return ConfigError(f"{self.where(key, *also)}: {key} {message}")

    def unknown_key(self, prefix: str, key: str, allowed: Sequence[str]) -> ConfigError:
        """An unknown key ``key`` in table ``prefix`` ("" for the top level)."""
        full = f"{prefix}.{key}" if prefix else key
        scope = f" in [{prefix}]" if prefix else ""
        return ConfigError(f"{self.where(full)}: unknown key {full!r}"
                           f"{did_you_mean(key, allowed)}; allowed keys{scope}: "
                           + ", ".join(allowed))


# --------------------------------------------------------------------------- pydantic


def _extra(model: type[BaseModel], field: str) -> dict:
    info = model.model_fields.get(field)
    extra = info.json_schema_extra if info is not None else None
    return extra if isinstance(extra, dict) else {}


def literal_values(annotation: Any) -> tuple | None:
    """The values of the first ``Literal[...]`` inside ``annotation`` (through
    ``Optional``, ``Annotated`` and unions), or None."""
    if typing.get_origin(annotation) is typing.Literal:
        return typing.get_args(annotation)
    for arg in typing.get_args(annotation):
        found = literal_values(arg)
        if found is not None:
            return found
    return None


def _dig(data: Any, loc: Sequence) -> Any:
    for part in loc:
        try:
            data = data[part]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def first_error(exc: ValidationError) -> dict:
    """The error to report: an unknown key first (a typo explains what follows), else
    the first in field order."""
    errors = exc.errors()
    for err in errors:
        if err["type"] == "extra_forbidden":
            return err
    return errors[0]


def from_validation_error(exc: ValidationError, model: type[BaseModel], raw: dict,
                          ctx: Context, prefix: str) -> ConfigError:
    """The ConfigError for pydantic's ``exc``, raised validating ``raw`` (the table at
    dotted ``prefix``) against ``model``.

    Unknown keys list the model's fields; a ``Literal`` field lists its values; any
    other field error reads ``<key> must be <wanted>, got <value>``, with ``wanted``
    from the field's ``json_schema_extra`` (a list field with ``item_wanted`` names the
    failing item, ``key[i]``). Errors raised by a model validator carry their own key
    and message (``PydanticCustomError`` context ``key``, ``also``, ``message``).
    """
    err = first_error(exc)
    loc = err["loc"]
    dotted = lambda name: f"{prefix}.{name}" if prefix else str(name)  # noqa: E731
    if err["type"] == "extra_forbidden":
        return ctx.unknown_key(prefix, str(loc[0]), list(model.model_fields))
    context = err.get("ctx") or {}
    if "key" in context:                     # a model validator's cross-field error
        also = context.get("also") or ()
        where = ctx.where(context["key"], *also)
        hint = context.get("override_hint", "") if where == OVERRIDE_LABEL else ""
        return ConfigError(f"{where}: {context['key']} {context['message']}{hint}")
    field = str(loc[0]) if loc else ""
    extra = _extra(model, field)
    key, value = dotted(field), _dig(raw, loc[:1])
    allowed = literal_values(model.model_fields[field].annotation) \
        if field in model.model_fields else None
    if allowed is not None and err["type"] == "literal_error":
        if len(loc) > 1 and isinstance(loc[1], int):        # an item of a list field
            key, value = f"{key}[{loc[1]}]", _dig(raw, loc[:2])
        return ctx.error(key, f"= {show(value)} is not allowed; allowed: "
                         + ", ".join(map(str, allowed)))
    wanted = extra.get("wanted", "valid")
    if "item_wanted" in extra and len(loc) > 1 and isinstance(loc[1], int) \
            and isinstance(value, (list, tuple)):
        key, value, wanted = f"{key}[{loc[1]}]", _dig(raw, loc[:2]), extra["item_wanted"]
    got = f"{type_name(value)} {show(value)}" if extra.get("table") else show(value)
    return ctx.error(key, f"must be {wanted}, got {got}")
