"""Heap policy A/B (``shadowlab.core.heap``): ``retain`` against ``system`` in
alternating fresh processes (the policy is process-wide, and glibc's dynamic mmap
threshold cannot be restored once set, so one process cannot run both arms).

Each process applies its policy, renders the frame at 1024x1024, and calls every method
1 + CALLS times; it reports per method the median wall time of the last CALLS calls and
of each stage, the minor page faults and the user and system CPU time per call
(``getrusage``), a hash of the lit mask (which must agree between the arms), and the
1-minute load average and steal before it started. Within a round ``retain`` runs
first.

usage: python docs/repro/heap_policy_ab.py ROUNDS CALLS OUT.json METHODS "SCENE [k=v ...]" ...
  e.g. python docs/repro/heap_policy_ab.py 2 5 heap.json silhouette,izb "fuzzy triangles=100000"
"""
import json
import os
import subprocess
import sys

from shadowlab.core.machine import steal_seconds

CHILD = r"""
import hashlib, json, os, resource, statistics, sys, time
from shadowlab.core.heap import set_heap_policy
arm, methods, name, *rest = sys.argv[1:]
applied = set_heap_policy(arm)
import numpy as np
import shadowlab as sl
from shadowlab.scene.procedural import default_view
params = {k: json.loads(v) for k, v in (a.split("=", 1) for a in rest)}
scene = sl.load_scene(name, **params)
view = default_view(name, scene)
gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(1024, 1024)))
calls = int(os.environ["HEAP_AB_CALLS"])
out = {"policy": applied}
for method in methods.split(","):
    sl.compute_shadows(scene, gbuf, view.light, method=method)
    walls, stages = [], []
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    for _ in range(calls):
        t = time.perf_counter()
        r = sl.compute_shadows(scene, gbuf, view.light, method=method)
        walls.append(time.perf_counter() - t)
        stages.append(r.timings)
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    out[method] = {
        "wall_ms": 1e3 * statistics.median(walls),
        "stages_ms": {k: 1e3 * statistics.median(s.get(k, 0.0) for s in stages)
                      for k in stages[-1]},
        "faults_per_call": (r1.ru_minflt - r0.ru_minflt) / calls,
        "user_ms_per_call": 1e3 * (r1.ru_utime - r0.ru_utime) / calls,
        "sys_ms_per_call": 1e3 * (r1.ru_stime - r0.ru_stime) / calls,
        "lit_sha1": hashlib.sha1(np.packbits(np.asarray(r.lit)).tobytes()).hexdigest()}
print(json.dumps(out))
"""


def main(rounds: int, calls: int, out_path: str, methods: str, cases: list[str]) -> None:
    env = dict(os.environ, HEAP_AB_CALLS=str(calls))
    env.pop("SHADOWLAB_HEAP", None)
    record = {"rounds": rounds, "calls": calls, "methods": methods.split(","), "cases": {}}
    for case in cases:
        runs = {"retain": [], "system": []}
        for _ in range(rounds):
            for arm in ("retain", "system"):
                load = os.getloadavg()[0]
                steal0 = steal_seconds()
                res = subprocess.run([sys.executable, "-c", CHILD, arm, methods,
                                      *case.split()], env=env, check=True,
                                     capture_output=True, text=True)
                row = json.loads(res.stdout.strip().splitlines()[-1])
                row["load_before"] = load
                steal1 = steal_seconds()
                row["steal_seconds"] = (None if steal0 is None or steal1 is None
                                        else round(steal1 - steal0, 2))
                runs[arm].append(row)
                print(case, arm, {m: round(row[m]["wall_ms"]) for m in record["methods"]},
                      flush=True)
        hashes = {m: {r[m]["lit_sha1"] for arm in runs for r in runs[arm]}
                  for m in record["methods"]}
        record["cases"][case] = {"runs": runs,
                                 "same_lit_masks": {m: len(h) == 1 for m, h in hashes.items()}}
    with open(out_path, "w") as f:
        json.dump(record, f, indent=1)
    for case, data in record["cases"].items():
        print(case)
        for m in record["methods"]:
            cols = []
            for arm in ("retain", "system"):
                rows = [r[m] for r in data["runs"][arm]]
                wall = " / ".join(f"{r['wall_ms']:.0f}" for r in rows)
                sys_ms = " / ".join(f"{r['sys_ms_per_call']:.0f}" for r in rows)
                faults = " / ".join(f"{r['faults_per_call'] / 1e3:.1f}k" for r in rows)
                cols.append(f"{arm} wall {wall} ms, sys {sys_ms} ms, faults {faults}")
            print(f"  {m}: " + "; ".join(cols) + f"; same lit masks: {data['same_lit_masks'][m]}")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5:])
