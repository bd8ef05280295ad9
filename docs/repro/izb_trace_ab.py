"""A/B of the IZB's tracing engine (``JaxEngine.trace``) against a base commit's, on the
inputs captured from one frame.

Whole frames of fuzzy 100k vary by +-15 % from process to process on this machine,
more than a change to one stage moves them. This script renders each scene's frame once
with the working tree, captures the arguments of ``izb.JaxEngine.trace`` (fragments,
lists, samples, planes), loads the base commit's ``shadowlab/methods/izb.py`` as a
separate module (called directly, never through the method registry) and times the two
engines' ``trace`` alternately on the same arguments, after a first call of each that
compiles and checks that both return the same shadow mask, per-sample tests and
fragment counts.

Both engines get the fragments the working tree's raster made for its own engine. Since
c28f096 that engine reads only the fill's ``depth_class`` (the depth test moved into
the fill), so a base before c28f096, whose engine reads the triangle, slot, coverage and
minimum depth, cannot be compared with this script: compare whole frames with
``commit_ab.py`` instead.

usage: python docs/repro/izb_trace_ab.py BASE REPS OUT.json "SCENE [k=v ...]" ...
  e.g. python docs/repro/izb_trace_ab.py aa8ecb5 7 out.json "fuzzy triangles=100000"
"""
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

import shadowlab as sl
from shadowlab.methods import izb, registry
from shadowlab.scene.procedural import default_view
from shadowlab.structures import light_raster as lr


def captured_trace_args(name: str, params: dict) -> tuple:
    """The arguments of the working tree's ``JaxEngine.trace`` in one izb frame (1024x1024,
    default view, ``verify=False``)."""
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(1024, 1024)))
    captured, trace = {}, izb.JaxEngine.trace

    def spy(*args):
        captured["args"] = args
        return trace(*args)

    izb.JaxEngine.trace = staticmethod(spy)
    try:
        sl.compute_shadows(scene, gbuf, view.light, method="izb", verify=False)
    finally:
        izb.JaxEngine.trace = staticmethod(trace)
    if "args" not in captured:
        raise SystemExit("the izb frame did not call the working tree's JaxEngine.trace")
    return captured["args"]


def _load(base: str, path: str, name: str, tmp: str):
    """Module ``name`` from ``path`` in commit ``base``, written to ``tmp`` and loaded."""
    file = os.path.join(tmp, name.rsplit(".", 1)[-1] + ".py")
    with open(file, "w") as f:
        f.write(subprocess.check_output(["git", "show", f"{base}:{path}"], text=True))
    spec = importlib.util.spec_from_file_location(name, file)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod            # dataclasses look their module up while defined
    spec.loader.exec_module(mod)
    return mod


def base_module(base: str, tmp: str):
    """The base commit's izb module, loaded under another name, with the base commit's
    light raster as its ``lr`` (the engine calls raster helpers that later commits
    removed). Its ``register`` call would replace the working tree's ``izb`` in the
    method registry: the entry is put back, so that frames still run the working
    tree's method."""
    raster = _load(base, "shadowlab/structures/light_raster.py",
                   "shadowlab.structures._light_raster_base", tmp)
    entry = registry._REGISTRY["izb"]
    try:
        mod = _load(base, "shadowlab/methods/izb.py", "shadowlab.methods._izb_base", tmp)
    finally:
        registry._REGISTRY["izb"] = entry
    mod.lr = raster
    return mod


def timed(trace, args):
    with lr.x64():
        t = time.perf_counter()
        out = trace(*args)
        return time.perf_counter() - t, out


def main(base: str, reps: int, out: str, cases: list[str]) -> None:
    sha = subprocess.check_output(["git", "rev-parse", base], text=True).strip()
    head = subprocess.check_output(["git", "rev-parse", "HEAD"], text=True).strip()
    if subprocess.check_output(["git", "status", "--porcelain", "--", "shadowlab"], text=True):
        head += " + uncommitted changes"
    with tempfile.TemporaryDirectory() as tmp:
        old = base_module(base, tmp).JaxEngine.trace
    new = izb.JaxEngine.trace
    rows = []
    for case in cases:
        name, *kv = case.split()
        params = {k: json.loads(v) for k, v in (a.split("=", 1) for a in kv)}
        args = captured_trace_args(name, params)
        (_, a), (_, b) = timed(new, args), timed(old, args)
        same = (np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
                and tuple(a[2:]) == tuple(b[2:]))
        if not same:
            raise SystemExit(f"{case}: the engines disagree")
        times = {"new": [], "old": []}
        load = os.getloadavg()[0]
        for _ in range(reps):
            for arm, trace in (("new", new), ("old", old)):
                times[arm].append(round(1e3 * timed(trace, args)[0], 1))
        row = {"case": case, "load_1min_start": load, "load_1min_end": os.getloadavg()[0],
               "trace_ms": times, "median_ms": {k: statistics.median(v) for k, v in
                                                times.items()}, "identical": same}
        print(json.dumps(row), flush=True)
        rows.append(row)
    with open(out, "w") as f:
        json.dump({"base": sha, "new": head, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4:])
