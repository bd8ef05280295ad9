"""Minimal reproduction: XLA:CPU segfaults when the process cannot map more memory regions.

Fills the process's region budget (vm.max_map_count) with small anonymous mappings of
alternating protection (so the kernel cannot merge them), leaving HEADROOM regions free,
then compiles one small jitted function. With HEADROOM=20 XLA logs "LLVM compilation
error: Cannot allocate memory" and the process dies with SIGSEGV inside
backend_compile_and_load; with HEADROOM=2000 it compiles and runs. Linux only.

    python docs/repro/xla_map_count.py 20     # exit 139 (segfault)
    python docs/repro/xla_map_count.py 2000   # prints the sum, exit 0
"""
import faulthandler
import mmap
import sys

import jax
import jax.numpy as jnp


def mapped_regions() -> int:
    with open("/proc/self/maps", "rb") as f:
        return f.read().count(b"\n")


faulthandler.enable()
limit = int(open("/proc/sys/vm/max_map_count").read())
headroom = int(sys.argv[1]) if len(sys.argv) > 1 else 20
jnp.ones(3).block_until_ready()                      # start the CPU backend first
held = []
while mapped_regions() < limit - headroom:
    for _ in range(max(1, min(2000, (limit - headroom - mapped_regions()) // 2))):
        prot = mmap.PROT_READ if len(held) % 2 else mmap.PROT_READ | mmap.PROT_WRITE
        held.append(mmap.mmap(-1, 4096, prot=prot))
print(f"{mapped_regions()} of {limit} regions mapped; compiling", flush=True)
f = jax.jit(lambda x: jnp.sin(x) + jnp.cumsum(x) - jnp.sort(x))
print(float(f(jnp.ones(100)).sum()), flush=True)
print("compiled and ran", flush=True)
