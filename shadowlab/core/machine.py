"""The machine a measurement ran on: its CPU (model, count and widest vector
instructions) and load, recorded with every timed result (``shadowlab bench``,
``bench --cold``, ``shadowlab figures`` and each checkpointed sweep point), so that a
time can be judged against the load it was taken under and compared only with times
taken on the same kind of CPU. XLA compiles for the host's vector width, so the same
code runs at different speeds on CPUs with and without AVX-512."""

from __future__ import annotations

import datetime
import os
import platform


#: 1-minute load average per core above which a run is marked as not idle
BUSY_LOAD_PER_CORE = 0.25


def load_average() -> list[float] | None:
    """The 1, 5 and 15-minute load averages, rounded to 0.01 (None where the platform
    has none)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


#: x86 vector extensions from the widest down, as (cpuinfo flag, name in reports)
SIMD_LEVELS = (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"),
               ("sse4_2", "SSE4.2"))


def cpu_description(cpuinfo: str | None = None) -> dict:
    """The CPU's model name and widest vector extension: ``{"model": str | None, "simd":
    str | None}``. Read from ``/proc/cpuinfo`` (or the given text of such a file) on
    Linux; where this host's file names no model, or cannot be read, the model is
    ``platform.processor()`` (given text gets no such fallback), and without the file
    ``simd`` is None. ARM's Advanced SIMD is reported as "NEON" (flag ``asimd``)."""
    own = cpuinfo is None                  # this host: its platform may name the model
    if own:
        try:
            with open("/proc/cpuinfo") as f:
                cpuinfo = f.read()
        except OSError:
            return {"model": platform.processor() or None, "simd": None}
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, sep, value = line.partition(":")
        key = key.strip().lower()
        if sep and key not in fields:
            fields[key] = value.strip()
    flags = set((fields.get("flags") or fields.get("features") or "").split())
    simd = next((name for flag, name in SIMD_LEVELS if flag in flags), None)
    if simd is None and "asimd" in flags:
        simd = "NEON"
    model = fields.get("model name") or fields.get("cpu model") \
        or (platform.processor() if own else None)
    return {"model": model or None, "simd": simd}


def machine_state() -> dict:
    """Date (UTC), CPU count and description (:func:`cpu_description`) and load averages
    (1, 5, 15 min; None where the platform has none) of this machine now."""
    return {"date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d"),
            "cpus": os.cpu_count(), "cpu": cpu_description(), "load_average": load_average()}


def machine_record(before: dict, after: dict, note: str | None = None) -> dict:
    """The ``machine`` entry of a bench, cold-start or figures JSON: the CPU (where
    ``before`` describes it), the load before and after the run, and a note that says
    when the machine was busy when the run started (1-minute load above
    ``BUSY_LOAD_PER_CORE`` per core) besides the user's ``note``. The load after the run
    is recorded but not judged: it counts the run's own threads."""
    rec = {"date_utc": before["date_utc"], "cpus": before["cpus"]}
    if before.get("cpu"):
        rec["cpu"] = before["cpu"]
    rec |= {"load_average_before": before["load_average"],
            "load_average_after": after["load_average"]}
    notes = [note] if note else []
    start = before["load_average"][0] if before["load_average"] else None
    if start is not None and start > BUSY_LOAD_PER_CORE * (before["cpus"] or 1):
        notes.append(f"not idle at the start: 1-minute load average {start:.2f} on "
                     f"{before['cpus']} cores (other jobs, or the tail of one that just "
                     f"ended), so times may be slower than on an idle machine")
    if notes:
        rec["note"] = "; ".join(notes)
    return rec
