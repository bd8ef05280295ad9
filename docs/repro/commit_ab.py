"""Whole-frame A/B of two commits in alternating processes.

A change that replaces module-level functions cannot be compared reliably in one
process by patching (a second copy of a method module registers itself again, and the
registry then calls the copy's own helpers), and this machine's speed drifts over
minutes. So each case runs in fresh processes, alternately on the working tree
(``new``) and on a git worktree of ``BASE`` (``old``), ROUNDS times each. Every process
renders the frame, calls the method 7 times and reports the median of the last 5 calls'
stage times, a hash of the lit mask (which must agree between the arms) and the scalar
counters of the last call (the summary names those that differ, with both arms' values;
per-pixel counter maps are not compared), the file its shadowlab
was imported from (checked against its tree) and the 1-minute load average before it
started. Within a round ``new`` runs first.

usage: python docs/repro/commit_ab.py BASE ROUNDS OUT.json "METHOD SCENE [k=v ...] [o.opt=v ...]" ...
  k=v: scene parameters; o.opt=v: method options (JSON values), e.g.
  python docs/repro/commit_ab.py HEAD~1 2 ab.json "izb fuzzy triangles=100000"
"""
import json
import os
import subprocess
import sys
import tempfile

FRAME = r"""
import hashlib, json, statistics, sys
import numpy as np
import shadowlab as sl
from shadowlab.scene.procedural import default_view
method, name, *rest = sys.argv[1:]
params, opts = {}, {}
for a in rest:
    k, v = a.split("=", 1)
    (opts if k.startswith("o.") else params)[k.removeprefix("o.")] = json.loads(v)
scene = sl.load_scene(name, **params)
view = default_view(name, scene)
gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(1024, 1024)))
runs = [sl.compute_shadows(scene, gbuf, view.light, method=method, **opts) for _ in range(7)]
r = runs[-1]
scalars = {k: np.asarray(v).item() for k, v in r.counters.items() if np.ndim(v) == 0}
digest = hashlib.sha1(np.packbits(r.lit).tobytes()).hexdigest()
print(json.dumps({"lit_hash": digest[:12], "counters": scalars, "module": sl.__file__, "stages_ms": {
    k: round(1e3 * statistics.median(x.timings[k] for x in runs[2:]), 1) for k in r.timings}}))
"""


def main(base: str, rounds: int, out: str, cases: list[str]) -> None:
    root = subprocess.check_output(["git", "rev-parse", "--show-toplevel"], text=True).strip()
    head = subprocess.check_output(["git", "rev-parse", "HEAD"], cwd=root, text=True).strip()
    dirty = bool(subprocess.check_output(["git", "status", "--porcelain", "--", "shadowlab"],
                                         cwd=root, text=True).strip())
    with tempfile.TemporaryDirectory() as tmp:
        old = os.path.join(tmp, "base")
        rows = []
        try:
            subprocess.check_call(["git", "worktree", "add", "-q", "--detach", old, base],
                                  cwd=root)
            base_sha = subprocess.check_output(["git", "rev-parse", "HEAD"], cwd=old,
                                               text=True).strip()
            for case in cases:
                for i in range(rounds):
                    for arm, tree in (("new", root), ("old", old)):
                        load = os.getloadavg()[0]
                        env = dict(os.environ, PYTHONPATH=tree)
                        res = subprocess.run([sys.executable, "-c", FRAME, *case.split()],
                                             env=env, cwd=tmp, capture_output=True, text=True)
                        if res.returncode:
                            raise SystemExit(f"{arm} {case!r} failed:\n{res.stderr[-2000:]}")
                        row = {"case": case, "arm": arm, "round": i, "load_1min": load,
                               **json.loads(res.stdout.strip().splitlines()[-1])}
                        if not os.path.realpath(row["module"]).startswith(
                                os.path.realpath(tree) + os.sep):
                            raise SystemExit(f"{arm} imported {row['module']}, not {tree}")
                        rows.append(row)
                        print(json.dumps(row), flush=True)
        finally:
            subprocess.call(["git", "worktree", "remove", "--force", old], cwd=root)
            subprocess.call(["git", "worktree", "prune"], cwd=root)
    summary = {}
    for case in cases:
        arms = {a: [r for r in rows if r["case"] == case and r["arm"] == a]
                for a in ("new", "old")}
        totals = {a: [r["stages_ms"]["total"] for r in v] for a, v in arms.items()}
        hashes = {r["lit_hash"] for v in arms.values() for r in v}
        counters = [r["counters"] for v in arms.values() for r in v]
        names = sorted(set().union(*counters))
        # repr: a counter missing from one arm differs, and NaN equals NaN
        differ = [k for k in names if len({repr(c.get(k)) for c in counters}) > 1]
        summary[case] = {"total_ms": totals, "identical_lit": len(hashes) == 1,
                         "differing_counters": {k: {a: v[0]["counters"].get(k) for a, v in
                                                    arms.items()} for k in differ},
                         "ratio_new_to_old": round(sum(totals["new"]) / sum(totals["old"]), 3)}
        print(case, summary[case])
    with open(out, "w") as f:
        json.dump({"base": base_sha, "new": head + (" + uncommitted changes" if dirty else ""),
                   "cases": summary, "runs": rows}, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4:])
