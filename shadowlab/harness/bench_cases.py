"""The built-in benchmark cases (``shadowlab/configs/bench.toml``) and their targets.

A light module (no JAX, no method code), so that ``bench_report`` reads targets without
importing the methods.
"""

from __future__ import annotations

import copy
import functools
import tomllib
from importlib import resources


@functools.lru_cache(maxsize=1)
def _table() -> dict:
    """bench.toml, parsed once per process (it ships with the package)."""
    return tomllib.loads(resources.files("shadowlab").joinpath("configs/bench.toml").read_text())


def default_cases(size: str = "full") -> list[dict]:
    """The built-in cases (``shadowlab/configs/bench.toml``): [{name, overrides}] (a
    copy: the caller may change it)."""
    return copy.deepcopy(_table()[size]["case"])


def builtin_case(name: str | None) -> dict:
    """The built-in case called ``name`` (bench.toml, either size), or {}."""
    for size in ("full", "ci"):
        for c in default_cases(size):
            if c["name"] == name:
                return c
    return {}


def case_repeats(name: str | None, repeats: int) -> int:
    """``repeats``, capped by the built-in case's own ``repeats`` (bench.toml) if it has one
    (cases whose single run takes minutes)."""
    c = builtin_case(name)
    return max(1, min(repeats, int(c["repeats"]))) if "repeats" in c else repeats


def case_target(name: str | None) -> float | None:
    """The built-in case's ``target`` (bench.toml): the largest static ratio to the Embree
    pass that its issue asks of each method, or None."""
    target = builtin_case(name).get("target")
    return None if target is None else float(target)


def target_verdict(ratio, target) -> str | None:
    """"met" / "missed" for a static ratio against a target, None without either."""
    if ratio is None or target is None:
        return None
    return "met" if ratio <= target else "missed"
