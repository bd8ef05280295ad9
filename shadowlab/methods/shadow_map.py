"""``shadow_map``: the shadow-map baseline (approximate), see docs/shadow_map.md.

A depth map rendered from the light (``shadowlab.structures.light_raster``, standard
coverage at texel centres, nearest caster kept per texel), looked up at every view
sample: a sample is lit when its light-space depth is not beyond the stored depth plus a
bias. The light camera (``shadowlab.scene.light_camera``) is fitted to the view samples:
orthographic for a directional light, one perspective face or a cube for a point light.
Only texels that some lookup reads are rasterized (the result is identical to a full
map; the cost is proportional to the lookups, not R x R).

Bias modes (``bias``): ``none``; ``constant`` (``bias_constant`` texel footprints of
linear depth at the receiver); ``slope`` (glPolygonOffset-like at map creation:
``bias_factor`` x the depth slope per texel + ``bias_units`` float32 ulps); ``normal``
(normal offset: the lookup point moves ``bias_normal`` texel footprints along the
normal). ``pcf`` filters 3 x 3 texels (lit where at least half the comparisons pass).
"""

from __future__ import annotations

import numpy as np

from ..core.frame import precision_mode, view_samples
from ..core.result import ShadowResult
from ..core.timing import StageTimer
from ..scene.light_camera import box_corners, fit_light_camera
from ..scene.view import DirectionalLight, hard_light
from ..structures import light_raster as lr
from .interface import MethodError
from .registry import Option, register

RESOLUTIONS = (512, 1024, 2048, 4096, 8192)
BIASES = ("none", "constant", "slope", "normal")
PROJECTIONS = ("auto", "perspective", "cube")
#: texels around each triangle's box: none, since a texel whose centre the triangle
#: covers has its centre within the triangle's box (the box is the floor of the
#: projected extremes; a centre outside it is at least half a texel outside, far beyond
#: the rounding of the edge functions)
BOX_PAD = 0.0


def fit_camera(scene, samples, light, resolution: int, projection: str, padding: int = 1):
    """The light camera fitted to the samples' positions (casters: the scene's box).

    ``projection`` applies to point lights; a directional light is orthographic. The
    extent depends on ``resolution / padding`` only, so ``(k R, k)`` gives the grid of
    ``(R, 1)`` with every texel split into k x k."""
    light = hard_light(light)
    proj = "auto" if isinstance(light, DirectionalLight) else projection
    try:
        return fit_light_camera(light, samples.position, casters=box_corners(scene.bounds),
                                resolution=resolution, projection=proj, padding=padding)
    except ValueError as err:
        raise MethodError(f"option projection={projection!r}: {err}; allowed: "
                          f"{', '.join(PROJECTIONS)} ('auto' picks a cube)") from err


@register("shadow_map", doc="shadow map from the light (depth map at texel centres, bias "
          "modes, optional 3x3 PCF); approximate", kind="approximate",
          paper="Williams 1978 (shadow maps); the baseline of Peciva et al. 2013 and "
                "Tokuyoshi & Mizokuchi 2018",
          counters=("samples", "casters", "culled_triangles", "sm_fragments", "light_faces",
                    "light_texels", "shadowed", "lit"),
          stages=("samples", "light_setup", "raster", "lookup"),
          options={
              "resolution": Option(8192, "texels per side of each light face (R x R)",
                                   allowed=RESOLUTIONS),
              "projection": Option("auto", "point lights: one fitted perspective face, a "
                                   "cube, or auto (directional lights: orthographic)",
                                   allowed=PROJECTIONS),
              "bias": Option("slope", "depth bias mode", allowed=BIASES),
              "bias_constant": Option(2.0, "constant bias: texel footprints of linear depth "
                                      "at the receiver", kind=float, minimum=0.0),
              "bias_factor": Option(1.0, "slope bias: multiple of the depth slope per texel",
                                    kind=float, minimum=0.0),
              "bias_units": Option(4.0, "slope bias: float32 ulps of the stored depth",
                                   kind=float, minimum=0.0),
              "bias_normal": Option(1.0, "normal offset: texel footprints along the normal",
                                    kind=float, minimum=0.0),
              "pcf": Option(False, "3x3 percentage-closer filtering (lit where >= half pass)",
                            allowed=(False, True)),
          })
def shadow_map(scene, gbuf, light, *, precision, shadow_eps, resolution, projection, bias,
               bias_constant, bias_factor, bias_units, bias_normal, pcf):
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    counters = {"samples": samples.count, "casters": 0,
                "culled_triangles": scene.num_triangles, "sm_fragments": 0,
                "light_faces": 0, "light_texels": 0}
    if samples.count == 0:
        for name in ("light_setup", "raster", "lookup"):
            timer.times[name] = 0.0
        lit = np.zeros(gbuf.valid.shape, bool)
        counters.update(shadowed=0, lit=0)
        return ShadowResult(lit, counters, dict(timer.times, total=timer.total))
    with precision_mode(precision) as dtype:
        with timer.stage("light_setup"):
            cam = fit_camera(scene, samples, light, resolution, projection)
            r = cam.resolution[0]
            points = samples.position
            if bias == "normal":
                w = lr.texel_world_size(cam, points)
                points = points + (bias_normal * w)[:, None] * samples.normal
            face, uv, key, delta = lr.project_points(cam, points)
            if pcf:
                col, row = key % r, (key // r) % r
                looks = []
                for dv in (-1, 0, 1):
                    for du in (-1, 0, 1):
                        c = np.clip(col + du, 0, r - 1)
                        w_ = np.clip(row + dv, 0, r - 1)
                        looks.append((face.astype(np.int64) * r + w_) * r + c)
                look = np.stack(looks, axis=1)
            else:
                look = key[:, None]
            keys = lr.unique_keys(look.ravel(), len(cam.faces) * r * r)[0]
            setups = [lr.setup_face(f, scene.triangles, pad=BOX_PAD) for f in cam.faces]
            ok = np.any(np.stack([s.ok for s in setups]), axis=0)
        with timer.stage("raster"):
            with lr.x64():
                wanted = ("slot", "centre") + (("slope",) if bias == "slope" else ())
                frags = lr.raster(setups, keys, r, "standard", fields=("covered",) + wanted)
                got = dict(zip(wanted, frags.compact(*wanted)))
            slot, depth_c = got["slot"], got["centre"]
            if bias == "slope":
                slope = got["slope"]
                ulp = np.spacing(np.abs(depth_c).astype(np.float32)).astype(np.float64)
                depth_c = depth_c + bias_factor * slope + bias_units * ulp
            dmap = np.full(len(keys), np.inf)
            np.minimum.at(dmap, slot, depth_c)
            dmap = dmap.astype(dtype)
        with timer.stage("lookup"):
            stored = dmap[np.searchsorted(keys, look)]                 # [S, k]
            d = delta.astype(dtype)[:, None]
            if bias == "constant":
                # compare linear depth along the face axis, k texel footprints apart
                foot = lr.texel_world_size(cam, samples.position).astype(dtype)[:, None]
                if cam.kind == "orthographic":
                    passed = d <= stored + dtype(bias_constant) * foot
                else:
                    near = dtype(cam.near)
                    with np.errstate(divide="ignore"):
                        zmap = np.where(np.isfinite(stored), -near / stored, np.inf)
                    z = -near / d
                    passed = z <= zmap + dtype(bias_constant) * foot
            else:
                passed = d <= stored
            lit_values = passed.mean(axis=1) >= 0.5 if pcf else passed[:, 0]
    lit = samples.scatter(lit_values, fill=False)
    counters.update({
        "casters": int(ok.sum()), "culled_triangles": int(scene.num_triangles - ok.sum()),
        "sm_fragments": int(len(slot)), "light_faces": len(cam.faces),
        "light_texels": int(len(keys)),
        "shadowed": int(samples.count - lit_values.sum()), "lit": int(lit.sum())})
    return ShadowResult(lit, counters, dict(timer.times, total=timer.total))
