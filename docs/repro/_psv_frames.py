"""Shared set-up of the repro scripts: scene specs and frames (all of them), and the PSV
query's inputs."""
import os

import numpy as np

import shadowlab as sl
from shadowlab.core.frame import localize, view_samples
from shadowlab.methods import psv as psvm
from shadowlab.methods.registry import call_options
from shadowlab.scene.procedural import default_view
from shadowlab.scene.view import hard_light
from shadowlab.structures import top_tree as tt

#: (query, depth test) of each TOP-tree method
QUERIES = {"psv": ("stack", False), "d_psv": ("stack", True),
           "d_stackless": ("stackless", True), "d_hybrid": ("hybrid", True)}


def frame(spec: str, res: int):
    """(scene, view, G-buffer) of a spec ``name[:k=v,k=v]`` (integer parameters) at
    ``res`` x ``res`` pixels, from the scene's default view."""
    name, _, params = spec.partition(":")
    kw = {k: int(v) for k, v in (p.split("=") for p in params.split(",") if p)}
    scene = sl.load_scene(name, **kw)
    view = default_view(name, scene)
    return scene, view, sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))


def method_rows(specs, res: int, methods):
    """Per scene spec and method: (scene, view, G-buffer, method, row), the row a dict
    that starts with the spec, its triangle count, the method and the 1-minute load."""
    for spec in specs:
        scene, view, gbuf = frame(spec, res)
        for m in methods:
            yield scene, view, gbuf, m, {"scene": spec, "triangles": scene.num_triangles,
                                         "method": m, "load_start": os.getloadavg()[0]}


def query_inputs(scene, view, gbuf):
    """The float32 TOP tree of the methods' default options, built in the methods' frame
    ("light"), and the query's inputs: dict with tree, points [S, 3], scale [S], key [S],
    light_h [4] and the options ``o``."""
    local = localize(scene, gbuf, view.light, "light")
    o = call_options("psv", {})
    samples = view_samples(local.gbuf, local.light)
    light_h = hard_light(local.light).homogeneous
    tree, scale, _ = psvm.build_tree(
        local.scene, local.light, local.gbuf.camera, samples, dtype=np.float32,
        shadow_eps=o["shadow_eps"], bias=o["bias"], order=o["order"], seed=o["seed"],
        wedge=o["wedge"], classify_ulps=o["classify_ulps"], face_culling=o["face_culling"])
    return {"tree": tree, "points": samples.position.astype(np.float32), "scale": scale,
            "key": tt.light_key(samples.position, light_h), "light_h": light_h, "o": o}


def keep_kernels_per_flag(flag):
    """Make ``psv``'s cached kernel builders keep one kernel per value of ``flag()`` (a
    module setting read at trace time), so that an A/B alternating the setting compiles
    each variant once."""
    kernels = {}

    def keep(cached):
        def get(*args):
            key = (cached, flag(), args)
            if key not in kernels:
                cached.cache_clear()
                kernels[key] = cached(*args)
            return kernels[key]
        return get

    psvm._chunk_kernel = keep(psvm._chunk_kernel)
    psvm._init_kernel = keep(psvm._init_kernel)
    psvm._compact_kernel = keep(psvm._compact_kernel)


def query_flag_ab(specs, res: int, methods, pairs: int, set_flag, labels: tuple) -> list:
    """A/B of a query setting over the breadth-first tree of each scene spec: per scene
    and method, both settings once (compile, and a check that every output is the same),
    then ``pairs`` alternating pairs timing the query's chunk kernels (stage "query").

    ``set_flag(query, on)`` sets the module setting; ``labels``: names of the off and on
    times in the rows ("<label>_ms"). Returns the rows (also printed)."""
    import os
    import statistics

    from shadowlab.core.timing import StageTimer

    rows = []
    for spec in specs:
        scene, view, gbuf = frame(spec, res)
        q = query_inputs(scene, view, gbuf)
        q["tree"] = q["tree"].renumbered(tt.breadth_first_volumes(q["tree"]))
        for m in methods:
            query, depth = QUERIES[m]
            stack = call_options(m, {}).get("stack_size", 0)

            def run(on):
                set_flag(query, on)
                timer = StageTimer()
                got = psvm.run_query(q["tree"], q["points"], q["scale"], q["key"],
                                     q["light_h"], query=query, depth_test=depth,
                                     wedge=q["o"]["wedge"], stack_size=stack, timer=timer)
                return got, timer.times["query"]

            first = {on: run(on)[0] for on in (False, True)}
            same = all(np.array_equal(first[False][k], first[True][k]) for k in first[False])
            times = {False: [], True: []}
            load = os.getloadavg()[0]
            for _ in range(pairs):
                for on in (False, True):
                    times[on].append(run(on)[1])
            med = {on: statistics.median(t) for on, t in times.items()}
            row = {"scene": spec, "triangles": scene.num_triangles, "method": m,
                   "load_start": load, "load_end": os.getloadavg()[0], "identical": same,
                   f"{labels[0]}_ms": [round(1e3 * x, 1) for x in times[False]],
                   f"{labels[1]}_ms": [round(1e3 * x, 1) for x in times[True]],
                   "ratio_of_medians": med[True] / med[False]}
            rows.append(row)
            print(f"{spec} {m}: {labels[0]} {1e3 * med[False]:.0f} ms, {labels[1]} "
                  f"{1e3 * med[True]:.0f} ms (x{row['ratio_of_medians']:.3f}), identical {same}",
                  flush=True)
    return rows
