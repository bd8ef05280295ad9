"""Refusing work too large for the machine, before anything is allocated.

:func:`estimate_run_bytes` adds up the arrays a run holds per pixel (the byte counts
below follow the dtypes of :func:`shadowlab.reference.raycast.render_gbuffer`,
:func:`shadowlab.reference.raycast.reference_shadows` and :mod:`shadowlab.harness.run`):

- per frame, transient: the primary rays (origins and directions, float64 x 3 each),
  Embree's hit record, the G-buffer (position and normal float64 x 3, depth float64,
  triangle int32, valid bool), the reference's shadow rays (origin, direction float64
  x 3, length float64) and one method's working set (float32 samples and normals,
  int64 counters), methods running one after another;
- kept for every frame until the outputs are written (and stacked once more when they
  are): the valid and reference masks, each method's result (a bool mask, or float64
  visibility for a soft method) and per-pixel int64 counter maps (at most six; the
  soft methods have five), and the float64 soft reference when a soft method runs.

:func:`memory_limit` is a fraction (:data:`MEMORY_FRACTION`) of the memory available
now (``MemAvailable`` of ``/proc/meminfo``, else ``os.sysconf``), or the bytes given by
the environment variable ``SHADOWLAB_MEMORY_LIMIT`` (``8GiB``, ``512M``, ``1e9``).
"""

from __future__ import annotations

import dataclasses
import os
import re
from typing import Sequence

from .errors import ConfigError

#: The environment variable that overrides the memory limit.
ENV_VAR = "SHADOWLAB_MEMORY_LIMIT"
#: The share of the available memory a run may plan to use.
MEMORY_FRACTION = 0.75

# Bytes per pixel (see the module docstring).
PRIMARY_RAYS = 2 * 3 * 8            # origins, directions: float64 [H, W, 3]
EMBREE_HITS = 48                    # float32 ray copies, tfar, u, v, primID, geomID
GBUFFER = 3 * 8 + 3 * 8 + 8 + 4 + 1  # position, normal, depth, triangle, valid
REFERENCE_RAYS = 3 * 8 + 3 * 8 + 8 + 1  # shadow-ray origin, direction, length; lit
METHOD_WORK = 3 * 4 + 3 * 4 + 6 * 8 + 8  # float32 samples, normals; counters; lit
KEPT_FRAME = 1 + 1                  # valid, reference
KEPT_METHOD = 8 + 6 * 8             # lit (float64 for soft), up to six int64 maps
KEPT_SOFT = 8                       # float64 soft reference
STACK_COPIES = 2                    # the per-frame lists and their np.stack


@dataclasses.dataclass(frozen=True)
class MemoryEstimate:
    """Estimated peak bytes of a run.

    Attributes:
        pixels: width x height of one frame.
        frames: frames of the run.
        per_frame: transient bytes of one frame (G-buffer, rays, one method at work).
        kept: bytes kept over all frames until the outputs are written.
    """

    pixels: int
    frames: int
    per_frame: int
    kept: int

    @property
    def total(self) -> int:
        """Peak bytes: one frame at work plus everything kept."""
        return self.per_frame + self.kept


def estimate_run_bytes(resolution: Sequence[int], frames: int = 1, methods: int = 1,
                       soft: bool = False) -> MemoryEstimate:
    """The memory a run of ``methods`` methods over ``frames`` frames of
    ``resolution`` = (width, height) pixels needs (see the module docstring)."""
    pixels = int(resolution[0]) * int(resolution[1])
    per_pixel = PRIMARY_RAYS + EMBREE_HITS + GBUFFER + REFERENCE_RAYS \
        + (METHOD_WORK if methods else 0)
    kept_pixel = KEPT_FRAME + methods * KEPT_METHOD + (KEPT_SOFT if soft else 0)
    return MemoryEstimate(pixels=pixels, frames=int(frames), per_frame=pixels * per_pixel,
                          kept=pixels * kept_pixel * int(frames) * STACK_COPIES)


_UNITS = {"": 1, "b": 1, "k": 1024, "kb": 1000, "kib": 1024, "m": 1024**2, "mb": 1000**2,
          "mib": 1024**2, "g": 1024**3, "gb": 1000**3, "gib": 1024**3, "t": 1024**4,
          "tb": 1000**4, "tib": 1024**4}


def parse_bytes(text: str) -> int:
    """``"8GiB"``, ``"512M"`` (binary), ``"2GB"`` (decimal), ``"1e9"`` -> bytes.

    Raises:
        ValueError: not a positive amount with a known unit.
    """
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", text)
    if not m or m.group(2).lower() not in _UNITS:
        raise ValueError(f"{text!r} is not an amount of memory such as 8GiB, 512M or 1e9")
    value = float(m.group(1)) * _UNITS[m.group(2).lower()]
    if not value >= 1:
        raise ValueError(f"{text!r} is not a positive amount of memory")
    return int(value)


def format_bytes(n: float) -> str:
    """``"224 GiB"``: bytes in binary units, three significant digits."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    raise AssertionError  # pragma: no cover


def available_memory() -> int | None:
    """Bytes of memory available now (``MemAvailable``, else free pages), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def memory_limit() -> tuple[int | None, str]:
    """(bytes a run may use, how that was decided); bytes None = unknown (no check).

    Raises:
        ConfigError: ``SHADOWLAB_MEMORY_LIMIT`` is set but is not an amount of memory.
    """
    text = os.environ.get(ENV_VAR)
    if text is not None and text.strip():
        try:
            limit = parse_bytes(text)
        except ValueError as exc:
            raise ConfigError(f"{ENV_VAR}: {exc}") from None
        return limit, f"set by {ENV_VAR}={text.strip()}"
    avail = available_memory()
    if avail is None:
        return None, "the available memory is unknown"
    return int(avail * MEMORY_FRACTION), (f"{MEMORY_FRACTION:.0%} of the "
                                          f"{format_bytes(avail)} available")


def check_run_memory(config) -> MemoryEstimate:
    """Refuse ``config`` (a :class:`~shadowlab.config.RunConfig`) if its estimate
    exceeds :func:`memory_limit`; return the estimate.

    Raises:
        ConfigError: naming the resolution, frames and methods, the estimate, the
            limit and how to change them.
    """
    from .. import methods as registry
    from ..scene.procedural import DEFAULT_RESOLUTION

    resolution = config.camera.resolution or DEFAULT_RESOLUTION
    names = config.methods.names
    soft = any(registry.get(n).soft for n in names)
    est = estimate_run_bytes(resolution, config.animation.frames, len(names), soft)
    limit, how = memory_limit()
    if limit is None or est.total <= limit:
        return est
    where = config.where("camera.resolution", "animation.frames")
    frames = config.animation.frames
    raise ConfigError(
        f"{where}: camera.resolution = [{resolution[0]}, {resolution[1]}] is too large for "
        f"this machine: {est.pixels:,} pixels x {frames} frame{'s' if frames != 1 else ''} "
        f"with {len(names)} method{'s' if len(names) != 1 else ''} need an estimated "
        f"{format_bytes(est.total)} ({format_bytes(est.per_frame)} for a frame at work, "
        f"{format_bytes(est.kept)} kept for the outputs), more than the limit of "
        f"{format_bytes(limit)} ({how}); lower camera.resolution, animation.frames or "
        f"methods.names, or set {ENV_VAR} (e.g. {ENV_VAR}=64GiB)")
