"""The machine a measurement ran on: its CPU count and load, recorded with every timed
result (``shadowlab bench``, ``bench --cold``, ``shadowlab figures`` and each
checkpointed sweep point), so that a time can be judged against the load it was taken
under."""

from __future__ import annotations

import datetime
import os


#: 1-minute load average per core above which a run is marked as not idle
BUSY_LOAD_PER_CORE = 0.25


def load_average() -> list[float] | None:
    """The 1, 5 and 15-minute load averages, rounded to 0.01 (None where the platform
    has none)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def machine_state() -> dict:
    """Date (UTC), CPU count and load averages (1, 5, 15 min; None where the platform
    has none) of this machine now."""
    return {"date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d"),
            "cpus": os.cpu_count(), "load_average": load_average()}


def machine_record(before: dict, after: dict, note: str | None = None) -> dict:
    """The ``machine`` entry of a bench, cold-start or figures JSON: load before and after the run, and a note
    that says when the machine was busy when the run started (1-minute load above
    ``BUSY_LOAD_PER_CORE`` per core) besides the user's ``note``. The load after the run
    is recorded but not judged: it counts the run's own threads."""
    rec = {"date_utc": before["date_utc"], "cpus": before["cpus"],
           "load_average_before": before["load_average"],
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
