"""``shadowlab bench --cold``: each method's cold start, in a fresh process.

What a user waits for the first time a method runs: a new Python process, whose JAX
persistent compilation cache (``SHADOWLAB_JAX_CACHE``) is a new, empty folder, imports
shadowlab, builds the config's scene and G-buffer, and calls the method. Only the JAX
cache is empty: the operating system's file cache is warm (the parent has just imported
the same libraries), so ``import_seconds`` is a fresh process's import, not a first
import after boot. Per method of a run config (default: the built-in default run,
``gate`` at 256x256) the child process reports, in seconds:

- ``import_seconds``: ``import shadowlab`` (JAX, Embree, the method registry);
- ``setup_seconds``: the scene, its first view and the G-buffer;
- ``first_call_seconds``: the first ``compute_shadows`` call, wall clock: tracing,
  compiling and running (the cold start proper);
- ``compile_seconds``: of that, what the method's jitted stages report as
  ``<stage>_compile`` (trace, lower and compile of each; host work is the rest);
- ``warm_seconds``: the median of ``repeats`` further calls with the same options (the
  config's, without the static options ``shadowlab bench`` adds for its static ratio);
- ``cache_entries_at_start``: files in the compilation cache when the child started
  (0: a cold start);

and the parent adds ``process_seconds``, the child's wall clock from spawn to exit.
A first call is compared with :data:`TARGET_SECONDS`. The machine's load before and
after is recorded as ``shadowlab bench`` records it.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the cold-start aim for a method's first call on the default run (seconds)
TARGET_SECONDS = 20.0

_CHILD = ("import sys, time; t0 = time.perf_counter(); "
          "from shadowlab.harness.cold_start import child; child(t0, *sys.argv[1:])")


def child(t0: float, out_path: str, config_path: str, overrides_json: str, method: str,
          repeats: str) -> None:
    """The child process: measure one method's cold start and write it as JSON to
    ``out_path`` (a file, so whatever a method prints cannot mix with the result)."""
    from ..config import load_config
    from ..core.heap import set_heap_policy
    from ..core.jaxcache import enable_compilation_cache
    from ..methods import compute_shadows
    from ..reference.raycast import render_gbuffer

    heap = set_heap_policy()                     # the parent's, from $SHADOWLAB_HEAP
    cache = enable_compilation_cache()           # the parent's empty folder
    entries = sum(1 for _ in cache.iterdir())
    t1 = time.perf_counter()
    config = load_config(config_path or None, json.loads(overrides_json))
    scene = config.build_scene()
    view = config.views(scene)[0]
    gbuf = render_gbuffer(scene, view.camera)
    options = {"shadow_eps": config.reference.shadow_eps,
               **config.methods.options.get(method, {})}
    t2 = time.perf_counter()
    result = compute_shadows(scene, gbuf, view.light, method=method, **options)
    t3 = time.perf_counter()
    warm = []
    for _ in range(int(repeats)):
        s = time.perf_counter()
        compute_shadows(scene, gbuf, view.light, method=method, **options)
        warm.append(time.perf_counter() - s)
    Path(out_path).write_text(json.dumps({
        "cache_entries_at_start": entries, "heap": heap, "scene": scene.name,
        "triangles": scene.num_triangles,
        "resolution": list(view.camera.resolution),
        "import_seconds": t1 - t0, "setup_seconds": t2 - t1, "first_call_seconds": t3 - t2,
        "compile_seconds": float(sum(v for k, v in result.timings.items()
                                     if k.endswith("_compile"))),
        "warm_seconds": statistics.median(warm) if warm else None}))


def cold_start(config_path: str | None = None, overrides=(), repeats: int = 3,
               progress: bool = True, timeout: float = 1800.0,
               note: str | None = None) -> dict:
    """Cold start of every method of a run config (each in its own fresh process with
    an empty compilation cache); a JSON-able dict (module docstring).

    Methods that cannot use the config's light are listed as skipped. A child that
    fails is recorded with the tail of its stderr, and the others still run.

    Raises:
        ConfigError: an invalid config (before any process starts).
    """
    from ..config import load_config
    from ..core import io
    from ..methods import light_problem
    from ..core.machine import machine_record, machine_state

    config = load_config(config_path, list(overrides))       # refuse a bad config first
    scene_light = config.views(config.build_scene())[0].light
    before = machine_state()
    rows = {}
    names = list(config.methods.names)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(names), unit="method", file=sys.stderr)
    for name in names:
        if bar is not None:
            bar.set_description(f"cold start {name}")
        reason = light_problem(name, scene_light)
        if reason is not None:
            rows[name] = {"skipped": reason}
        else:
            rows[name] = _measure(config_path, list(overrides), name, repeats, timeout)
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    first = next((r for r in rows.values() if "scene" in r), {})
    return {"provenance": io.provenance(), "kind": "cold_start",
            "config": config_path or "<built-in default>", "overrides": list(overrides),
            "scene": first.get("scene"), "triangles": first.get("triangles"),
            "resolution": first.get("resolution"), "repeats": repeats,
            "target_seconds": TARGET_SECONDS, "methods": rows,
            "machine": machine_record(before, machine_state(), note)}


def _measure(config_path, overrides, name, repeats, timeout) -> dict:
    import shadowlab
    from ..core.heap import heap_policy

    # the child imports this very shadowlab, wherever the command runs from
    package_parent = str(Path(shadowlab.__file__).resolve().parent.parent)
    with tempfile.TemporaryDirectory(prefix="shadowlab-cold-") as tmp:
        cache, out = Path(tmp) / "jax", Path(tmp) / "result.json"
        env = dict(os.environ, SHADOWLAB_JAX_CACHE=str(cache), SHADOWLAB_HEAP=heap_policy(),
                   PYTHONPATH=os.pathsep.join(
                       [package_parent] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
        t0 = time.perf_counter()
        try:
            proc = subprocess.run([sys.executable, "-c", _CHILD, str(out), config_path or "",
                                   json.dumps(overrides), name, str(repeats)],
                                  env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired as exc:
            tail = (exc.stderr or b"")[-600:]
            tail = tail.decode(errors="replace") if isinstance(tail, bytes) else tail
            return {"failed": f"no result within {timeout:.0f} s; stderr: {tail.strip()}"}
        wall = time.perf_counter() - t0
        try:
            row = json.loads(out.read_text()) if proc.returncode == 0 else None
        except (OSError, ValueError) as exc:
            row, proc.stderr = None, f"{proc.stderr}\nno readable result: {exc}"
    if row is None:
        return {"failed": f"exit status {proc.returncode}: {proc.stderr.strip()[-600:]}"}
    row["process_seconds"] = wall
    row["within_target"] = row["first_call_seconds"] <= TARGET_SECONDS
    return row


def format_cold(results: dict) -> str:
    """The cold-start table as ``shadowlab bench --cold`` prints it."""
    w, h = results["resolution"] or (0, 0)
    lines = []
    note = results["machine"].get("note")
    if note:
        lines.append(f"machine: {note}")
    lines.append(f"cold start: {results['scene']} {results['triangles']} triangles {w}x{h}, "
                 f"each method in a fresh process with an empty compilation cache "
                 f"(target: first call <= {results['target_seconds']:.0f} s)")
    lines.append(f"  {'method':<16} {'import s':>8} {'setup s':>8} {'first s':>8} "
                 f"{'compile s':>9} {'warm ms':>8} {'process s':>9}  target")
    for name, r in results["methods"].items():
        if "skipped" in r or "failed" in r:
            lines.append(f"  {name:<16} {'skipped' if 'skipped' in r else 'FAILED'}: "
                         f"{r.get('skipped') or r.get('failed')}")
            continue
        warm = "-" if r["warm_seconds"] is None else f"{1000 * r['warm_seconds']:.1f}"
        lines.append(f"  {name:<16} {r['import_seconds']:>8.2f} {r['setup_seconds']:>8.2f} "
                     f"{r['first_call_seconds']:>8.2f} {r['compile_seconds']:>9.2f} "
                     f"{warm:>8} {r['process_seconds']:>9.2f}  "
                     f"{'ok' if r['within_target'] else 'MISSED'}")
    return "\n".join(lines)


__all__ = ["TARGET_SECONDS", "cold_start", "format_cold"]
