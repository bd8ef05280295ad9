"""Atomic output files: an interrupted run never leaves a half-written file.

Every writer writes to a temporary file in the destination folder and renames it
into place (``os.replace`` is atomic on POSIX and Windows within one file system).
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ""):
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix,
                               dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def jsonable(obj):
    """Tuples, NumPy arrays and scalars, Paths and non-finite floats as JSON values."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


#: Separates a generated document (docs/benchmarks.md, docs/claims.md) from the
#: hand-written text below it, which regeneration keeps.
KEEP_MARKER = "<!-- end of generated part: text below this line is kept on regeneration -->"


def write_generated(path, generated: str) -> Path:
    """Write ``generated``, then :data:`KEEP_MARKER`, then the text that an existing
    ``path`` has below its marker (nothing for a new file), atomically."""
    path = Path(path)
    tail = "\n"
    if path.exists():
        old = path.read_text()
        if KEEP_MARKER in old:
            tail = old.split(KEEP_MARKER, 1)[1]
    text = generated + "\n" + KEEP_MARKER + tail
    return write_text(path, text if text.endswith("\n") else text + "\n")


def write_json(path, data) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(jsonable(data), indent=2, sort_keys=False) + "\n")
    return Path(path)


def write_npz(path, arrays: dict) -> Path:
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **{k: np.asarray(v) for k, v in arrays.items()})
    return Path(path)


def save_figure(fig, path, dpi: int = 110) -> Path:
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=Path(path).suffix.lstrip(".") or "png")
    plt.close(fig)
    return Path(path)


def provenance() -> dict:
    """Versions of the tools and the git commit, for the metadata of every output."""
    import jax
    import trimesh

    from .. import __version__

    commit = None
    with contextlib.suppress(Exception):
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).resolve().parent, timeout=5,
                                check=True).stdout.strip() or None
    return {"shadowlab": __version__, "commit": commit, "python": sys.version.split()[0],
            "jax": jax.__version__, "numpy": np.__version__, "trimesh": trimesh.__version__}
