"""The PSV query's tile loop A/B (docs/psv.md, "The stack stays in place across tiles"):
the same TOP tree (renumbered breadth-first, as the bench's static runs keep it) queried
with ``psv.STACK_IN_PLACE`` off (each tile's slice of the stack copied out of the buffer
and written back per chunk) and on (the tile's lanes address the whole buffer at their
tile's offset), in alternation in one process, with a check that every output is
identical. Times: the query's chunk kernels.
usage: python docs/repro/psv_stack_in_place_ab.py RES PAIRS OUT.json METHODS scene[:k=v,..]...
(METHODS: comma-separated among psv, d_psv, d_hybrid; d_stackless keeps no stack)
"""
import json, sys

from _psv_frames import keep_kernels_per_flag, query_flag_ab
from shadowlab.methods import psv as psvm

res, pairs, out, methods = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
if "d_stackless" in methods.split(","):
    sys.exit("d_stackless keeps no stack; choose among psv, d_psv, d_hybrid")
# Both variants' kernels are traced once and kept: the flag is read at trace time.
default = psvm.STACK_IN_PLACE
keep_kernels_per_flag(lambda: psvm.STACK_IN_PLACE)


def set_flag(query, in_place):
    psvm.STACK_IN_PLACE = in_place


rows = query_flag_ab(sys.argv[5:], res, methods.split(","), pairs, set_flag,
                     ("sliced", "in_place"))
psvm.STACK_IN_PLACE = default
with open(out, "w") as f:
    json.dump({"resolution": res, "pairs": pairs, "rows": rows}, f, indent=1)
