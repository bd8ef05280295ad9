"""Reading a run config: the TOML file, ``--set`` overrides, then validation.

Each table is validated by its pydantic model (:mod:`shadowlab.config.schema`), and a
failure becomes a :class:`~shadowlab.config.errors.ConfigError` naming the file (or
``--set``), the dotted key and what is allowed. What needs more than one table, or
the registries, is checked here: the generator parameters (by the generator's own
model), the method names and options (by the method registry), mesh paths (against
the config's folder) and the light type of ``animation.light_keys``. Last, the memory
a frame needs is estimated against the machine's limit
(:mod:`shadowlab.config.resources`).
"""

from __future__ import annotations

import os
import re
import tomllib
from importlib import resources as _package
from pathlib import Path
from typing import Any, Sequence

from pydantic import BaseModel, ValidationError

from ..core.io import jsonable
from ..scene import procedural
from ..scene.mesh import SUPPORTED_FORMATS, SceneError
from . import resources
from .errors import (BUILTIN_DEFAULT, OVERRIDE_LABEL, ConfigError, Context, did_you_mean,
                     from_validation_error, show)
from .schema import (AnimationConfig, CameraConfig, LightConfig, MethodsConfig, MethodsTable,
                     OutputConfig, ReferenceConfig, RunConfig, RunFile, SceneConfig,
                     SceneTable, NONZERO_VEC3)

_KEY_SEGMENT = re.compile(r"^[A-Za-z0-9_-]+$")


def load_config(path: str | os.PathLike | None = None,
                overrides: Sequence[str] = (), *, check_memory: bool = True) -> RunConfig:
    """Read, override and validate a run configuration.

    Args:
        path: a TOML file; ``None`` reads the built-in default
            (``shadowlab/configs/default.toml``).
        overrides: ``key=value`` strings (the CLI's ``--set``), applied in order; the
            value is parsed as a TOML value (``[256, 256]``, ``3``, ``"x"``, ``true``),
            and taken as a bare string if it is not one.
        check_memory: refuse a config whose frames need more memory than the machine
            allows (:func:`shadowlab.config.resources.check_run_memory`).

    Returns:
        The validated :class:`RunConfig`.

    Raises:
        ConfigError: a missing or unreadable file, a TOML syntax error, a malformed
            override, an unknown key, a value of the wrong type or range, or work too
            large for the machine.
    """
    data, label, base_dir, default_out = read_source(path)
    return config_from_data(data, label, base_dir, default_out, overrides,
                            check_memory=check_memory)


def read_source(path: str | os.PathLike | None) -> tuple[dict, str, Path, str]:
    """The parsed TOML of ``path`` (None: the built-in default), with its error label,
    the folder its relative paths resolve against and its default ``output.dir``."""
    if path is None:
        text = _package.files("shadowlab").joinpath("configs", "default.toml").read_text("utf-8")
        return parse_toml(text, BUILTIN_DEFAULT), BUILTIN_DEFAULT, Path.cwd(), "runs/default"
    p = Path(path)
    return (read_toml(p, str(path), what="config file"), str(path), p.resolve().parent,
            f"runs/{p.stem}")


def config_from_data(data: dict, label: str, base_dir: Path, default_out: str,
                     overrides: Sequence[str] = (), *, check_memory: bool = True) -> RunConfig:
    """Validate the parsed config ``data`` (the tables of a run config) after applying
    ``overrides``; errors name ``label`` (see :func:`load_config`)."""
    if isinstance(overrides, str):          # one override passed on its own
        overrides = (overrides,)
    override_keys = []
    for text in overrides:
        key, value = parse_override(text)
        _apply_override(data, key, value, text)
        override_keys.append(".".join(key))

    ctx = Context(label, base_dir, override_keys)
    tables = validate(RunFile, data, ctx, "")
    scene = _read_scene(ctx, tables.scene)
    camera = validate(CameraConfig, tables.camera, ctx, "camera")
    light = validate(LightConfig, tables.light, ctx, "light")
    animation = _read_animation(ctx, tables.animation, light)
    reference = validate(ReferenceConfig, tables.reference, ctx, "reference")
    methods = _read_methods(ctx, tables.methods, reference)
    output = validate(OutputConfig, {"dir": default_out, **tables.output}, ctx, "output")
    config = RunConfig(scene=scene, camera=camera, light=light, animation=animation,
                       methods=methods, reference=reference, output=output, source=label,
                       overrides=tuple(overrides))
    if check_memory:
        resources.check_run_memory(config)
    return config


def validate(model: type[BaseModel], raw: Any, ctx: Context, prefix: str):
    """``model`` validated from the table ``raw`` at dotted ``prefix``; a failure is a
    ConfigError (:func:`shadowlab.config.errors.from_validation_error`)."""
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        raise from_validation_error(exc, model, raw, ctx, prefix) from None


def read_toml(path: Path, label: str, what: str = "config file") -> dict:
    """The parsed TOML file ``path``; errors name ``label``."""
    if not path.exists():
        raise ConfigError(f"{label}: no such {what}")
    if path.is_dir():
        raise ConfigError(f"{label}: is a directory, not a {what}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{label}: cannot be read: {exc}") from exc
    return parse_toml(text, label)


def parse_toml(text: str, label: str) -> dict:
    """Parse TOML ``text``; a syntax error names ``label`` and the line."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        if "(at end of document)" in message:   # tomllib gives no line number there
            message = message.replace("(at end of document)",
                                      f"(at end of document, line {text.count(chr(10)) + 1})")
        raise ConfigError(f"{label}: invalid TOML: {message}") from exc


def parse_override(text: str) -> tuple[tuple[str, ...], Any]:
    """Split a ``key=value`` override into its dotted key path and its value.

    The value is parsed as a TOML value; if that fails it is kept as a bare string
    (so ``scene.source=fuzzy`` works without quotes).

    Raises:
        ConfigError: no ``=``, an empty key or key segment, or an empty value.
    """
    example = "expected key=value, e.g. camera.resolution=[256,256]"
    if not isinstance(text, str) or "=" not in text:
        raise ConfigError(f"{OVERRIDE_LABEL}: malformed override {text!r}: {example}")
    raw_key, _, raw_value = text.partition("=")
    key = tuple(part.strip() for part in raw_key.strip().split("."))
    if not raw_key.strip() or not all(_KEY_SEGMENT.match(part) for part in key):
        raise ConfigError(f"{OVERRIDE_LABEL}: malformed override {text!r}: the key must be "
                          f"dotted names such as scene.params.seed; {example}")
    raw_value = raw_value.strip()
    if not raw_value:
        raise ConfigError(f"{OVERRIDE_LABEL}: malformed override {text!r}: empty value; "
                          f"{example}")
    try:
        value = tomllib.loads(f"v = {raw_value}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw_value
    return key, value


def _apply_override(data: dict, key: tuple[str, ...], value: Any, text: str) -> None:
    """Set ``data[k0][k1]...[kn] = value``, creating tables on the way."""
    table = data
    for i, part in enumerate(key[:-1]):
        nxt = table.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"{OVERRIDE_LABEL}: override {text!r}: "
                              f"{'.'.join(key[:i + 1])} is a value, not a table")
        table = nxt
    table[key[-1]] = value


# --------------------------------------------------------------------------- tables


def _read_scene(ctx: Context, table: dict) -> SceneConfig:
    raw = validate(SceneTable, table, ctx, "scene")
    source, params = raw.source, raw.params
    generators = list(procedural.GENERATORS)
    if source in procedural.GENERATORS:
        return SceneConfig(source=source, params=_read_params(ctx, source, params))

    # A mesh file: resolve relative paths against the config folder (cwd for --set).
    base = Path.cwd() if ctx.where("scene.source") == OVERRIDE_LABEL else ctx.base_dir
    path = Path(source).expanduser()
    resolved = path if path.is_absolute() else (base / path)
    resolved = Path(os.path.normpath(resolved))
    if not resolved.is_file():
        state = "is a directory" if resolved.is_dir() else "does not exist"
        raise ctx.error("scene.source", f"= {source!r}{did_you_mean(source, generators)} is "
                        f"neither a procedural generator nor an existing mesh file ({resolved} "
                        f"{state}); generators: {', '.join(generators)}; mesh formats: "
                        + ", ".join("." + e for e in SUPPORTED_FORMATS))
    ext = resolved.suffix.lower().lstrip(".")
    if ext not in SUPPORTED_FORMATS:
        raise ctx.error("scene.source", f"= {source!r}: unknown mesh format '.{ext}'; allowed: "
                        + ", ".join("." + e for e in SUPPORTED_FORMATS))
    if params:
        raise ctx.error("scene.params", f"is only for procedural sources "
                        f"({', '.join(generators)}); scene.source = {source!r} is a mesh file",
                        "scene.source")
    return SceneConfig(source=str(resolved), params={})


def _read_params(ctx: Context, name: str, params: dict) -> dict[str, Any]:
    """Validate generator parameters with the generator's model
    (:func:`shadowlab.scene.procedural.resolve_params`); returns every parameter,
    defaults filled in."""
    defaults = dict(procedural.GENERATORS[name].defaults)
    unknown = [k for k in params if k not in defaults]
    if unknown:
        key = f"scene.params.{unknown[0]}"
        raise ConfigError(f"{ctx.where(key)}: unknown key {key!r}"
                          f"{did_you_mean(unknown[0], list(defaults))} for generator "
                          f"{name!r}; allowed keys in [scene.params]: "
                          + ", ".join(f"{k} (default {show(jsonable(v))})"
                                      for k, v in defaults.items()))
    out = dict(defaults)
    for k, value in params.items():
        key = f"scene.params.{k}"
        try:
            out[k] = procedural.resolve_params(name, **{k: value})[k]
        except SceneError as exc:
            raise ConfigError(f"{ctx.where(key)}: {key} = {show(value)} is not allowed: "
                              f"{exc}") from exc
    return out


def _read_animation(ctx: Context, table: dict, light: LightConfig) -> AnimationConfig:
    anim = validate(AnimationConfig, table, ctx, "animation")
    if light.type in ("directional", "sun") and anim.light_keys is not None:
        for i, vec in enumerate(anim.light_keys):   # directions: non-zero
            if not any(vec):
                raise ctx.error(f"animation.light_keys[{i}]", f"must be {NONZERO_VEC3}, got "
                                f"{show(table['light_keys'][i])}")
    return anim


def _read_methods(ctx: Context, table: dict, reference: ReferenceConfig) -> MethodsConfig:
    from .. import methods as registry

    raw = validate(MethodsTable, table, ctx, "methods")
    known = registry.names()
    every = raw.names == "all"
    if every:
        names = tuple(known)
    else:
        listed = [raw.names] if isinstance(raw.names, str) else raw.names
        if not isinstance(listed, (list, tuple)) or not listed or \
                not all(isinstance(n, str) for n in listed):
            raise ctx.error("methods.names", f'must be "all" or a non-empty list of method '
                            f"names; allowed: {', '.join(known)}; got {show(raw.names)}")
        for n in listed:
            if n not in known:
                raise ctx.error("methods.names", f"contains unknown method {n!r}"
                                f"{did_you_mean(n, known)}; allowed: {', '.join(known)} "
                                '(or "all")')
        dupes = sorted({n for n in listed if listed.count(n) > 1})
        if dupes:
            raise ctx.error("methods.names", f"lists {', '.join(map(repr, dupes))} more than "
                            "once")
        names = tuple(listed)

    given: dict[str, dict] = {}
    for method, opts in raw.options.items():
        key = f"methods.options.{method}"
        if method not in known:
            raise ConfigError(f"{ctx.where(key)}: unknown method {key!r}"
                              f"{did_you_mean(method, known)}; allowed methods: "
                              f"{', '.join(known)}")
        if not isinstance(opts, dict):
            raise ctx.error(key, f"must be a table of options, got {show(opts)}")
        for opt, value in opts.items():
            try:
                registry.resolve_options(method, {opt: value})
            except registry.MethodError as exc:
                raise ConfigError(f"{ctx.where(f'{key}.{opt}')}: {key}.{opt}: {exc}") from exc
        given[method] = dict(opts)

    options: dict[str, dict[str, Any]] = {}
    for method in names:
        opts = dict(given.get(method, {}))
        if "shadow_eps" in registry.get(method).options and "shadow_eps" not in opts:
            opts["shadow_eps"] = reference.shadow_eps
        try:
            options[method] = registry.resolve_options(method, opts)
        except registry.MethodError as exc:  # pragma: no cover - checked per key above
            raise ConfigError(f"{ctx.where(f'methods.options.{method}')}: "
                              f"methods.options.{method}: {exc}") from exc
    return MethodsConfig(names=names, options=options, all=every,
                         given={m: tuple(given.get(m, {})) for m in names})
