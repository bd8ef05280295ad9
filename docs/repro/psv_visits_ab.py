"""The PSV query's visit counter A/B (docs/psv.md, "Visit counts in the state word"):
the same TOP tree (renumbered breadth-first, as the bench's static runs keep it) queried
with the query's ``psv.VISITS_IN_WORD`` entry off (a per-lane counter array, one more
loop output) and on (a finished lane's count in its state word), for d_hybrid
``psv.HYBRID_FAST_IN_WORD`` (its stack-only step, until the first stall), in alternation
in one process, with a check that every output is identical. Times: the query's chunk
kernels (stage "query"; d_hybrid's one move of the counts into the array after a
stall is timed as a compaction and not included).
usage: python docs/repro/psv_visits_ab.py RES PAIRS OUT.json METHODS scene[:n=..,k=..]...
(METHODS: comma-separated, e.g. psv,d_psv,d_stackless,d_hybrid)
"""
import json, sys

from _psv_frames import keep_kernels_per_flag, query_flag_ab
from shadowlab.methods import psv as psvm

res, pairs, out, methods = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
# Both variants' kernels are traced once and kept: the flag is read at trace time.
default = dict(psvm.VISITS_IN_WORD), psvm.HYBRID_FAST_IN_WORD
keep_kernels_per_flag(lambda: (tuple(sorted(psvm.VISITS_IN_WORD.items())),
                               psvm.HYBRID_FAST_IN_WORD))


def set_flag(query, in_word):
    if query == "hybrid":
        psvm.HYBRID_FAST_IN_WORD = in_word
    else:
        psvm.VISITS_IN_WORD = dict(default[0], **{query: in_word})


rows = query_flag_ab(sys.argv[5:], res, methods.split(","), pairs, set_flag,
                     ("array", "in_word"))
psvm.VISITS_IN_WORD, psvm.HYBRID_FAST_IN_WORD = default
with open(out, "w") as f:
    json.dump({"resolution": res, "pairs": pairs, "rows": rows}, f, indent=1)
