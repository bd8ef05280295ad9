"""Experiment configs (``configs/experiments/<name>.<size>.toml``): parsed and checked.

An experiment's config is a flat TOML table read by ``experiments/<name>.py``. The
keys every experiment may use are declared by :class:`ExperimentConfig` (types and
ranges; unknown keys are refused, so a typo never silently falls back to an
experiment's default), and the scene parameters by the generators' own models:
``params`` holds the parameters of ``scene``, or, for an experiment over ``scenes``,
one table of parameters per generator name. Errors are
:class:`~shadowlab.config.errors.ConfigError` messages naming the file and the key.

:func:`load_experiment_file` returns the table exactly as parsed (a plain dict, the
experiments' input and what their JSON records), after validation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictStr

from ..scene import procedural
from ..scene.mesh import SceneError
from .errors import ConfigError, Context, did_you_mean, show
from .loading import read_toml, validate
from .schema import Resolution, Table, _wanted, number

_GENERATORS = ", ".join(procedural.GENERATORS)
Generator = Annotated[Literal[tuple(procedural.GENERATORS)], _wanted(
    f"a procedural generator name ({_GENERATORS})")]
Generators = Annotated[Optional[Annotated[list[Literal[tuple(procedural.GENERATORS)]],
                                          Field(min_length=1)]],
                       _wanted(f"a non-empty list of procedural generator names "
                               f"({_GENERATORS})")]


def _ints(minimum: int) -> Any:
    return Annotated[Optional[Annotated[list[Annotated[int, Field(strict=True, ge=minimum)]],
                                        Field(min_length=1)]],
                     _wanted(f"a non-empty list of integers >= {minimum}")]


_FRACTION = dict(ge=0, le=1, optional=True)


class ExperimentConfig(BaseModel):
    """Every key an experiment config may set (all optional here; each experiment
    reads the ones it needs). Resolutions in pixels (width, height), angles in
    degrees, fractions in [0, 1]."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    # what to render
    scene: Optional[Generator] = None
    scenes: Generators = None
    gain_scenes: Generators = None
    params: Table = {}
    options: Table = {}
    resolution: Resolution = None
    resolutions: Annotated[Optional[Annotated[list[Resolution], Field(min_length=1)]],
                           _wanted("a non-empty list of [width, height] resolutions",
                                   item_wanted="two positive integers [width, height]")] = None
    frames: number(int, ge=1, optional=True) = None
    repeats: number(int, ge=1, optional=True) = None
    slow_seconds: number(float, gt=0, unit=" (seconds)", optional=True) = None
    precision: Optional[Literal["float32", "float64"]] = None
    seeds: _ints(0) = None
    # method settings under study
    stack_sizes: _ints(1) = None
    grids: Annotated[Optional[Annotated[list[StrictStr], Field(min_length=1)]],
                     _wanted("a non-empty list of tile grids such as \"31x7\"")] = None
    overflow_capacity: number(int, ge=1, optional=True) = None
    expand_level: number(int, ge=0, optional=True) = None
    workers: _ints(1) = None
    # silhouette sweeps (experiments/silhouette_work.py)
    triangles_per_sphere_sweep: _ints(6) = None
    objects_sweep: _ints(1) = None
    per_triangle_max: number(int, ge=0, optional=True) = None
    shadow_map_resolutions: _ints(1) = None
    methods: Annotated[Optional[Annotated[list[StrictStr], Field(min_length=1)]],
                       _wanted("a non-empty list of method names")] = None
    offsets: Annotated[Optional[Annotated[list[Annotated[float, Field(ge=0)]],
                                          Field(min_length=1)]],
                       _wanted("a non-empty list of distances >= 0 (world units)")] = None
    max_exact_offset: number(float, ge=0, optional=True) = None
    world_coordinates: Annotated[Optional[StrictBool], _wanted("true or false")] = None
    # references and measurements
    truth_rays: number(int, ge=1, optional=True) = None
    embree_rays: _ints(1) = None
    distance_bins: number(int, ge=1, optional=True) = None
    crop: number(int, ge=1, optional=True) = None
    banding_sun_deg: number(float, gt=0, lt=90, unit=" (degrees)", optional=True) = None
    check_banding: Annotated[Optional[StrictBool], _wanted("true or false")] = None
    edge_sun_deg: number(float, gt=0, lt=45, unit=" (degrees)", optional=True) = None
    edge_resolution: number(int, ge=16, optional=True) = None
    raster_fragments: number(int, ge=1, optional=True) = None
    # checks and claims
    max_mismatch_fraction: number(float, **_FRACTION) = None
    max_bad_pixels_exact: number(int, ge=0, optional=True) = None
    max_mae: number(float, **_FRACTION) = None
    min_share_le_ptsv: number(float, **_FRACTION) = None
    min_gain: number(float, ge=0, optional=True) = None
    min_gain_at_discontinuities: number(float, ge=0, optional=True) = None
    min_one_pass_peak: number(float, ge=0, optional=True) = None
    max_two_pass_peak: number(float, ge=0, optional=True) = None
    min_peak_reduction: number(float, ge=0, optional=True) = None
    require_claims: Annotated[Optional[StrictBool], _wanted("true or false")] = None


def validate_experiment(data: dict, label: str) -> ExperimentConfig:
    """Validate a parsed experiment config; errors name ``label`` and the key.

    Raises:
        ConfigError: an unknown key, a wrong type or range, an unknown generator or
            generator parameter.
    """
    ctx = Context(label, Path("."), [])
    cfg = validate(ExperimentConfig, data, ctx, "")
    params = cfg.params
    if cfg.scenes is not None:                  # one table per generator
        for name, table in params.items():
            if name not in procedural.GENERATORS:
                raise ConfigError(f"{label}: unknown generator 'params.{name}'"
                                  f"{did_you_mean(name, list(procedural.GENERATORS))}; with "
                                  f"scenes, params holds one table per generator "
                                  f"({_GENERATORS})")
            if not isinstance(table, dict):
                raise ctx.error(f"params.{name}", f"must be a table of {name} parameters, "
                                f"got {show(table)}")
            _check_params(ctx, name, table, f"params.{name}")
    elif cfg.scene is not None:
        _check_params(ctx, cfg.scene, params, "params")
    return cfg


def _check_params(ctx: Context, name: str, params: dict, prefix: str) -> None:
    try:
        procedural.resolve_params(name, **params)
    except SceneError as exc:
        raise ConfigError(f"{ctx.label}: {prefix}: {exc}") from exc


def load_experiment_file(path: Path) -> dict:
    """The experiment config at ``path``, validated, as parsed (a plain dict).

    Raises:
        ConfigError: a missing or unreadable file, invalid TOML, or an invalid key
            (:func:`validate_experiment`).
    """
    data = read_toml(Path(path), str(path), what="experiment config")
    validate_experiment(data, str(path))
    return data
