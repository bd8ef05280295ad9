"""Ahead-of-time compilation of every kernel file to PTX for sm_80 and sm_90 without a
GPU (NVRTC inside warp-lang needs no CUDA driver), so the GPU path cannot rot unseen."""

import re

import pytest

pytest.importorskip("warp")

from shadowlab.kernels import aot  # noqa: E402


@pytest.mark.parametrize("arch", [80, 90])
def test_kernels_compile_to_ptx(arch):
    if not aot.nvrtc_available():
        pytest.skip("this warp-lang build has no NVRTC (CUDA toolkit) to compile CUDA with")
    out = aot.compile_ptx(arch)
    assert set(out) == set(aot.MODULES)
    expected = {"shadowlab.kernels.psv": ("top_insert", "top_query", "own_depth"),
                "shadowlab.kernels.sun_disk": ("rasterize",),
                "shadowlab.kernels.clustered_ptsv": (
                    "setup", "build_lanes", "build_tile", "compact_pointers", "existence_bits",
                    "pad_boxes", "traverse_lanes", "traverse_warp", "merge")}
    for name, path in out.items():
        ptx = path.read_bytes().decode("ascii", "replace")
        assert re.search(rf"^\.target sm_{arch}\b", ptx, re.M), name
        entries = re.findall(r"\.entry (\w+)_cuda_kernel_forward", ptx)
        for kernel in expected[name]:
            assert any(e.startswith(kernel + "_") for e in entries), (name, kernel)
        src = aot.cuda_source_path(path).read_text()
        assert "__global__" in src
    ptx = out["shadowlab.kernels.psv"].read_bytes().decode("ascii", "replace")
    assert "atom.global.cas" in ptx or "atom.cas" in ptx       # the CAS on the links
    # no contraction (fuse_fp=False -> --fmad=false): only the explicit XLA-matching FMAs
    # (plane value 2, light distance 2, symmetric wedge 1, signed wedge 2)
    assert len(re.findall(r"\bfma\.rn\.f32", ptx)) == 7
    # clustered PTSV: the atomics of Algorithm 1 (OR of accepts, AND when pruning, the job
    # counters), count-leading-zeros, popcount, and the faithful form's 32-lane reductions
    ptx = out["shadowlab.kernels.clustered_ptsv"].read_bytes().decode("ascii", "replace")
    for op in ("atom.global.or", "atom.global.and", "atom.global.add", "clz.b32", "popc.b32",
               "bar.sync"):
        assert op in ptx, op
    src = aot.cuda_source_path(out["shadowlab.kernels.clustered_ptsv"]).read_text()
    assert re.search(r"^#define WP_TILE_BLOCK_DIM 32$", src, re.M)     # a tile is one warp
