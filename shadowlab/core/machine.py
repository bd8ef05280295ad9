"""The machine a measurement ran on: its CPU (model, count and widest vector
instructions), its load and the CPU time a hypervisor took from it, recorded with every
timed result (``shadowlab bench``, ``bench --cold``, ``shadowlab figures`` and each
checkpointed sweep point), so that a time can be judged against the load it was taken
under and compared only with times taken on the same kind of CPU. XLA compiles for the
host's vector width, so the same code runs at different speeds on CPUs with and without
AVX-512. On a virtual machine the load average does not see other guests of the same
host; the kernel's *steal* time (CPU time the hypervisor gave to someone else while this
guest wanted it) does, where the hypervisor reports it."""

from __future__ import annotations

import datetime
import os
import platform
import time

from .heap import heap_policy

#: 1-minute load average per core above which a run is marked as not idle
BUSY_LOAD_PER_CORE = 0.25
#: share of the CPUs' time over a run (cores x wall time) that the hypervisor may take
#: (steal) before the run is marked as sharing its host
STEAL_SHARE = 0.02


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


def steal_seconds(stat: str | None = None) -> float | None:
    """Seconds of CPU time stolen from this machine since boot, summed over its CPUs:
    the 8th value (``steal``) of the aggregate ``cpu`` line of ``/proc/stat`` (or of the
    given text of such a file), in USER_HZ ticks. None where the file cannot be read or
    has no steal column (not Linux, or a kernel before 2.6.11)."""
    if stat is None:
        try:
            with open("/proc/stat") as f:
                stat = f.read()
        except OSError:
            return None
    for line in stat.splitlines():
        fields = line.split()
        if fields and fields[0] == "cpu":
            if len(fields) < 9:
                return None
            try:
                ticks = int(fields[8])
            except ValueError:
                return None
            try:
                hz = os.sysconf("SC_CLK_TCK")
            except (AttributeError, ValueError, OSError):
                hz = 100
            return ticks / hz
    return None


def cpu_clock() -> dict:
    """The clocks a span of a run is judged by: ``{"cpus": int, "clock": monotonic
    seconds, "steal": seconds stolen since boot or None}`` (:func:`steal_seconds`)."""
    return {"cpus": os.cpu_count(), "clock": time.monotonic(), "steal": steal_seconds()}


def steal_between(before: dict, after: dict) -> dict | None:
    """The CPU time the hypervisor took between two :func:`cpu_clock` (or
    :func:`machine_state`) readings: ``{"seconds": stolen, "share": stolen / (cores x
    wall time)}`` (rounded to 0.01 s and 0.0001), or None where either reading has no
    steal time or no wall time passed."""
    if before.get("steal") is None or after.get("steal") is None \
            or before.get("clock") is None or after.get("clock") is None:
        return None
    wall = after["clock"] - before["clock"]
    if wall <= 0:
        return None
    stolen = max(0.0, after["steal"] - before["steal"])
    return {"seconds": round(stolen, 2),
            "share": round(stolen / (wall * (before.get("cpus") or 1)), 4)}


def shared_host(steal: dict | None) -> bool:
    """Whether a steal record (:func:`steal_between`; None: not recorded) shows the
    hypervisor taking more than ``STEAL_SHARE`` of the cores' time."""
    return bool(steal) and steal["share"] > STEAL_SHARE


def steal_sentence(steal: dict | None) -> str | None:
    """A remark when the hypervisor took more than ``STEAL_SHARE`` of the CPUs' time
    (:func:`shared_host`), else None."""
    if not shared_host(steal):
        return None
    return (f"the hypervisor took {steal['seconds']:.2f} s of CPU time during the run "
            f"(steal: {100 * steal['share']:.1f} % of the cores' time): another guest "
            f"shared the host, so times may be slower than on an idle machine")


def machine_state() -> dict:
    """Date (UTC), CPU count and description (:func:`cpu_description`), load averages
    (1, 5, 15 min; None where the platform has none), the clocks of :func:`cpu_clock`
    of this machine now and the process's heap policy (:mod:`shadowlab.core.heap`)."""
    return {"date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d"),
            "cpu": cpu_description(), "load_average": load_average(), **cpu_clock(),
            "heap": heap_policy()}


def machine_record(before: dict, after: dict, note: str | None = None) -> dict:
    """The ``machine`` entry of a bench, cold-start or figures JSON: the CPU and the heap
    policy (where ``before`` describes them), the load before and after the run, the CPU time the
    hypervisor took during it (``steal``, :func:`steal_between`, where both states
    carry it), and a note that says when the machine was busy when the run started
    (1-minute load above ``BUSY_LOAD_PER_CORE`` per core) or shared its host (steal above
    ``STEAL_SHARE``) besides the user's ``note``. The load after the run is recorded but
    not judged: it counts the run's own threads."""
    rec = {"date_utc": before["date_utc"], "cpus": before["cpus"]}
    if before.get("cpu"):
        rec["cpu"] = before["cpu"]
    if before.get("heap"):
        rec["heap"] = before["heap"]
    rec |= {"load_average_before": before["load_average"],
            "load_average_after": after["load_average"]}
    steal = steal_between(before, after)
    if steal is not None:
        rec["steal"] = steal
    notes = [note] if note else []
    start = before["load_average"][0] if before["load_average"] else None
    if start is not None and start > BUSY_LOAD_PER_CORE * (before["cpus"] or 1):
        notes.append(f"not idle at the start: 1-minute load average {start:.2f} on "
                     f"{before['cpus']} cores (other jobs, or the tail of one that just "
                     f"ended), so times may be slower than on an idle machine")
    shared = steal_sentence(steal)
    if shared:
        notes.append(shared)
    if notes:
        rec["note"] = "; ".join(notes)
    return rec
