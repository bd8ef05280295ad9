"""Ahead-of-time compilation of the kernels for a CUDA architecture, without a GPU.

Warp generates CUDA C++ for each kernel module and compiles it with NVRTC, the CUDA
runtime compiler shipped inside the warp-lang wheel; NVRTC needs no GPU and no CUDA
driver, so ``wp.compile_aot_module(module, arch=80, use_ptx=True)`` produces PTX for
sm_80 on a CPU-only machine. The result is kept in the kernel cache (keyed by the
module's source hash), so only a changed kernel is compiled again.

    python -m shadowlab.kernels.aot [ARCH ...]     # default 80; prints the PTX paths
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from .runtime import init

#: kernel files compiled ahead of time
MODULES = ("shadowlab.kernels.psv", "shadowlab.kernels.sun_disk",
           "shadowlab.kernels.clustered_ptsv")


def nvrtc_available() -> bool:
    """Whether this Warp build can compile CUDA (NVRTC present), GPU or not."""
    import warp as wp

    init()
    return bool(getattr(wp._src.context.runtime, "toolkit_version", None))


def compile_ptx(arch: int = 80, modules=MODULES, module_dir=None) -> dict[str, Path]:
    """Compile every kernel module to PTX for ``sm_<arch>``; {module name: PTX path}."""
    import warp as wp

    init()
    out = {}
    for name in modules:
        mod = importlib.import_module(name)
        paths = wp.compile_aot_module(mod, arch=arch, use_ptx=True, module_dir=module_dir)
        out[name] = Path(paths[-1])
    return out


def cuda_source_path(ptx: Path) -> Path:
    """The generated CUDA C++ (what NVRTC compiled) next to a PTX file of compile_ptx."""
    return ptx.with_name(ptx.name.split(".sm")[0] + ".cu")


if __name__ == "__main__":
    archs = [int(a) for a in sys.argv[1:]] or [80]
    for a in archs:
        for name, path in compile_ptx(a).items():
            print(f"sm_{a}  {name}: {path}")
