"""The heap policy (``shadowlab.core.heap``): retained memory serves the next frame's
arrays without page faults, the command line applies and records it, and a bad policy
is refused with its source named."""

import json
import os
import platform
import subprocess
import sys

import pytest

from shadowlab.cli import main
from shadowlab.core import heap
from shadowlab.core.machine import machine_record, machine_state

# A child process: apply a policy, then allocate, write and free a 64 MiB array twice
# (above glibc's largest dynamic mmap threshold, 32 MiB), and print the minor page
# faults of the second round and the policy in force. NumPy's huge-page advice is off
# so that faults count 4 KiB pages.
_CHILD = """
import json, resource, sys
import numpy as np
from shadowlab.core.heap import set_heap_policy
policy = set_heap_policy(sys.argv[1])
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(2):
    before = faults()
    a = np.ones(8 * 1024 * 1024)
    a[::512] += 1.0
    del a
    second = faults() - before
print(json.dumps({"policy": policy, "faults": second}))
"""


def _run_child(policy: str) -> dict:
    env = dict(os.environ, NUMPY_MADVISE_HUGEPAGE="0")
    env.pop(heap.HEAP_ENV, None)
    out = subprocess.run([sys.executable, "-c", _CHILD, policy], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out)


def test_glibc_is_found_where_the_process_runs_on_it():
    # the tests below skip without glibc: a lookup broken on glibc must not skip them
    if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
        assert heap._libc() is not None


@pytest.mark.skipif(heap._libc() is None, reason="the heap policy needs glibc")
def test_retained_memory_serves_the_next_array_without_page_faults():
    retain, system = _run_child("retain"), _run_child("system")
    assert retain["policy"] == "retain" and system["policy"] == "system"
    # with the system's defaults the 64 MiB block is mapped afresh: one fault per page
    # touched (16,384 pages of 4 KiB, fewer with transparent huge pages); retained, it
    # is the first round's memory, already mapped
    assert system["faults"] >= 32
    assert retain["faults"] * 10 <= system["faults"]


def test_a_bad_policy_is_refused_with_its_source(monkeypatch, capsys):
    with pytest.raises(ValueError, match="heap policy must be one of retain, system; "
                                         "got 'keep'"):
        heap.resolve_policy("keep")
    monkeypatch.setenv(heap.HEAP_ENV, "keep")
    with pytest.raises(ValueError, match="SHADOWLAB_HEAP must be one of retain, system"):
        heap.resolve_policy()
    assert main(["methods"]) == 2
    assert "SHADOWLAB_HEAP must be one of retain, system; got 'keep'" in \
        capsys.readouterr().err
    monkeypatch.setenv(heap.HEAP_ENV, "")
    assert heap.resolve_policy() == "system"        # unset or empty: the default
    assert heap.resolve_policy("retain") == "retain"


def test_the_policy_in_force_is_recorded_with_the_machine():
    state = machine_state()
    assert state["heap"] == heap.heap_policy() == "system"     # the tests' (conftest)
    assert machine_record(state, state)["heap"] == "system"
    assert "heap" not in machine_record(dict(state, heap=None), state)


@pytest.mark.skipif(heap._libc() is None, reason="the heap policy needs glibc")
def test_the_command_line_applies_the_policy_it_is_given():
    code = ("import sys; from shadowlab.cli import main; from shadowlab.core import heap; "
            "main(sys.argv[1:]); print(heap.heap_policy())")
    env = {k: v for k, v in os.environ.items() if k != heap.HEAP_ENV}

    def policy(*args, **extra):
        return subprocess.run([sys.executable, "-c", code, *args], env=dict(env, **extra),
                              check=True, capture_output=True, text=True
                              ).stdout.split()[-1]
    assert policy("methods") == "system"
    assert policy("--heap", "retain", "methods") == "retain"
    assert policy("methods", SHADOWLAB_HEAP="retain") == "retain"
    assert policy("--heap", "system", "methods", SHADOWLAB_HEAP="retain") == "system"
