"""Golden CI-size arrays: the data behind every figure, kept so a change shows.

``tests/golden/<experiment>.npz`` holds the arrays an experiment's ``run`` returns at
CI size, minus its timings; ``tests/test_figures.py`` runs every experiment at CI size
anyway and compares its arrays with these (:func:`compare`):

- booleans, integers and strings (masks, counters, labels): exactly;
- other floats (means of counts, errors against a seeded reference): to
  ``RTOL``/``ATOL`` (NaN equals NaN), since XLA may round differently on another CPU;
- timings: not at all. A timing array is one whose name contains ``seconds`` or
  ``_stage_``, one
  listed in :data:`TIMINGS` for its experiment, or one the experiment module lists
  in its own ``TIMING_ARRAYS`` tuple (derived ratios of times count as timings);
- arrays an experiment module lists in ``CPU_DEPENDENT_ARRAYS``: not at all. They are
  counts that legitimately differ between CPUs (Embree breaks ties between coincident
  triangles differently with other vector widths); the module says why, and keeps a
  compared array beside each for what must not differ.

The full-size figures in ``figures/`` are separate and never compared.

A change that alters a figure's data fails until the goldens are regenerated on
purpose, with one command from the repository root::

    python -m shadowlab.harness.golden            # every experiment at CI size
    python -m shadowlab.harness.golden NAME ...   # only these

which runs the experiments at CI size (writing their figures to a temporary folder,
not to ``figures/``) and rewrites ``tests/golden/``; review ``git diff --stat`` and
commit.
"""

from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..core import io

RTOL = 1e-5
ATOL = 1e-9
#: Timing arrays per experiment besides those named ``*seconds*``.
TIMINGS: dict[str, tuple[str, ...]] = {
    "clustered_stages": ("stages", "total", "ptsv_total", "embree", "full_storage_total",
                         "no_ffc_total", "ptsv_build", "zfail_total", "zpass_total"),
    "soft_tiled_error": ("raster_ns_per_pair",),
    "psv_animation": ("accel_worst", "accel_mean", "accel_best"),
    "psv_queries": ("acceleration",),
}
_TIMING_NAME = re.compile(r"seconds|_stage_")     # *_stage_<name>: a stage's seconds


def golden_dir(root: Path) -> Path:
    return Path(root) / "tests" / "golden"


def timing_keys(name: str, arrays: dict, module=None) -> set[str]:
    """The keys of ``arrays`` that are timings (never compared)."""
    declared = set(TIMINGS.get(name, ())) | set(getattr(module, "TIMING_ARRAYS", ()))
    return {k for k in arrays if _TIMING_NAME.search(k) or k in declared}


def uncompared_keys(name: str, arrays: dict, module=None) -> set[str]:
    """The keys of ``arrays`` kept out of golden files: timings and the module's
    ``CPU_DEPENDENT_ARRAYS``."""
    return timing_keys(name, arrays, module) | (
        set(getattr(module, "CPU_DEPENDENT_ARRAYS", ())) & set(arrays))


def stripped(name: str, arrays: dict, module=None) -> dict[str, np.ndarray]:
    """``arrays`` without their uncompared keys (:func:`uncompared_keys`), as NumPy
    arrays."""
    skip = uncompared_keys(name, arrays, module)
    return {k: np.asarray(v) for k, v in arrays.items() if k not in skip}


def write(root: Path, name: str, arrays: dict, module=None) -> Path:
    """Write the golden file of experiment ``name`` (atomically)."""
    return io.write_npz(golden_dir(root) / f"{name}.npz", stripped(name, arrays, module))


def compare(root: Path, name: str, arrays: dict, module=None) -> list[str]:
    """What differs between ``arrays`` and the golden file of ``name``: a list of
    messages, empty when they agree (see the module docstring for the rules)."""
    path = golden_dir(root) / f"{name}.npz"
    if not path.exists():
        return [f"no golden file {path}; create it: python -m shadowlab.harness.golden {name}"]
    want = dict(np.load(path, allow_pickle=False))
    got = stripped(name, arrays, module)
    out = []
    for key in sorted(set(want) - set(got)):
        out.append(f"{key}: in the golden file, no longer produced")
    for key in sorted(set(got) - set(want)):
        out.append(f"{key}: new array, not in the golden file")
    for key in sorted(set(want) & set(got)):
        a, b = got[key], want[key]
        if a.shape != b.shape:
            out.append(f"{key}: shape {a.shape}, golden {b.shape}")
        elif a.dtype.kind in "fc" and b.dtype.kind in "fc":
            if not np.allclose(a, b, rtol=RTOL, atol=ATOL, equal_nan=True):
                bad = ~np.isclose(a, b, rtol=RTOL, atol=ATOL, equal_nan=True)
                out.append(f"{key}: {int(bad.sum())} of {a.size} values differ beyond "
                           f"rtol {RTOL:g} (first: {a[bad][0]!r}, golden {b[bad][0]!r})")
        elif a.dtype.kind != b.dtype.kind and not {a.dtype.kind, b.dtype.kind} <= {"i", "u"}:
            out.append(f"{key}: dtype {a.dtype}, golden {b.dtype}")
        elif not np.array_equal(a, b):
            bad = a != b
            out.append(f"{key}: {int(np.count_nonzero(bad))} of {a.size} values differ "
                       f"(first: {a[bad][0]!r}, golden {b[bad][0]!r})")
    return out


def regenerate(root: Path, only: list[str] | None = None, progress: bool = True) -> list[str]:
    """Run experiments at CI size and rewrite their golden files; return the names that
    failed (their golden files are left as they were)."""
    from .figures import discover, load_module, run_experiment

    found = discover(root)
    names = only or list(found)
    unknown = sorted(set(names) - set(found))
    if unknown:
        from .figures import ExperimentError

        raise ExperimentError(f"unknown experiment(s) {', '.join(unknown)}; available: "
                              f"{', '.join(found)}")
    failures = []
    with tempfile.TemporaryDirectory(prefix="shadowlab-golden-") as tmp:
        for name in names:
            try:
                arrays = run_experiment(root, name, "ci", out=Path(tmp))
            except Exception as exc:                 # a failing experiment: report it
                failures.append(name)
                print(f"{name}: FAILED ({type(exc).__name__}: {exc})", file=sys.stderr)
                continue
            path = write(root, name, arrays, load_module(found[name]))
            if progress:
                print(f"wrote {path}", file=sys.stderr)
    return failures


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    return 1 if regenerate(Path.cwd(), only=args or None) else 0


if __name__ == "__main__":
    sys.exit(main())
