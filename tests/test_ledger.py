"""The paper-claims ledger (docs/claims.md) is current, and the registry is consistent."""

import re
import types
from pathlib import Path

import pytest

from shadowlab.harness import claims as registry
from shadowlab.harness import ledger
from shadowlab.harness.figures import ExperimentError, discover, measure_claims

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "claims.md"


def test_ledger_regenerates_identically_from_the_committed_json(tmp_path):
    out = tmp_path / "claims.md"
    out.write_text(DOC.read_text())            # keeps the hand-written tail
    ledger.write_ledger(ROOT / "figures", out, ROOT)
    assert out.read_text() == DOC.read_text(), \
        "docs/claims.md is stale: run python -m shadowlab.harness.ledger"


def test_every_registered_claim_has_one_row():
    text = DOC.read_text().split(ledger.KEEP_MARKER)[0]
    for claim in registry.CLAIMS:
        assert len(re.findall(rf"^\| {re.escape(claim.id)} \|", text, re.M)) == 1, claim.id


def test_every_recorded_claim_appears_in_the_ledger():
    runs = ledger.load_runs(ROOT / "figures", ROOT)
    table = ledger.rows(runs)
    registered = {r["id"]: r for r in table}
    extra = ledger.unregistered(runs)
    for name, run in runs.items():
        for c in run["claims"]:
            if c.get("id") in registered:
                assert c["measured"] in registered[c["id"]]["measured"], (name, c)
            else:
                assert (name, c) in extra


def test_registry_is_consistent():
    ids = [c.id for c in registry.CLAIMS]
    assert len(ids) == len(set(ids))
    names = set(discover(ROOT))
    for c in registry.CLAIMS:
        assert c.paper in registry.PAPERS, c.id
        assert c.kind in ("quantitative", "qualitative"), c.id
        for e in c.experiments:      # an experiment of the repo, or a pattern for one to come
            assert e in names or "*" in e, (c.id, e)
        assert c.experiments or c.pending or c.tested_by, c.id   # a row says how or why not
        if c.tested_by:
            file, func = c.tested_by.split("::")
            assert f"def {func}(" in (ROOT / file).read_text(), c.tested_by


def test_unknown_claim_id_is_refused():
    mod = types.SimpleNamespace(claims=lambda a, c: [
        {"id": "s14.nope", "claim": "x", "measured": "1", "holds": True}])
    with pytest.raises(ExperimentError, match="unknown claim id 's14.nope'"):
        measure_claims(mod, {}, {})
    mod = types.SimpleNamespace(claims=lambda a, c: [
        registry.measured("s14.fig6.gain2x", "3.1x", True, label="gate")])
    (got,) = measure_claims(mod, {}, {})
    assert got["id"] == "s14.fig6.gain2x" and got["claim"].startswith("gate: ")


def test_verdicts_and_run_sizes_are_shown():
    runs = {"e": {"experiment": "e", "size": "ci", "config": {}, "_stale": False,
                  "provenance": {"commit": "0123456789"},
                  "claims": [registry.measured("s14.fig6.le_ptsv", "3 of 5", False, label="a"),
                             registry.measured("s14.fig6.le_ptsv", "5 of 5", True, label="b")]}}
    row = {r["id"]: r for r in ledger.rows(runs)}["s14.fig6.le_ptsv"]
    assert row["verdict"] == "fails 1 of 2"
    assert row["run"].startswith("CI (full pending)")
    assert "a: 3 of 5" in row["measured"] and row["why"]
    runs["e"]["size"] = "full"
    runs["e"]["claims"] = runs["e"]["claims"][1:]
    row = {r["id"]: r for r in ledger.rows(runs)}["s14.fig6.le_ptsv"]
    assert row["verdict"] == "holds" and row["run"].startswith("full") and row["why"] == ""
    assert {r["id"]: r for r in ledger.rows(runs)}["s14.fig1c.volume"]["verdict"] == \
        "not measured"


def test_an_untested_claim_is_neither_a_pass_nor_a_failure():
    """holds=None (the run could not test the claim, e.g. 0 of 0 culled) needs a note,
    reads 'untested' alone, and is left out of the verdict beside tested records."""
    mod = types.SimpleNamespace(claims=lambda a, c: [
        {"id": "s14.fig6.le_ptsv", "claim": "x", "measured": "0 of 0", "holds": None}])
    with pytest.raises(ExperimentError, match="needs a note"):
        measure_claims(mod, {}, {})
    mod = types.SimpleNamespace(claims=lambda a, c: [
        {"id": "s14.fig6.le_ptsv", "claim": "x", "measured": "0 of 0", "holds": None,
         "note": "nothing culled"}])
    (got,) = measure_claims(mod, {}, {})
    assert got["holds"] is None
    runs = {"e": {"experiment": "e", "size": "full", "config": {}, "_stale": False,
                  "provenance": {"commit": "0123456789"}, "claims": [got]}}
    row = {r["id"]: r for r in ledger.rows(runs)}["s14.fig6.le_ptsv"]
    assert row["verdict"] == "untested" and row["why"] == "nothing culled"
    runs["e"]["claims"].append(registry.measured("s14.fig6.le_ptsv", "2 of 5", False))
    row = {r["id"]: r for r in ledger.rows(runs)}["s14.fig6.le_ptsv"]
    assert row["verdict"] == "fails"
    assert "| paper | claims | holds | fails | untested | not measured |" in ledger.render(runs)


def test_runs_table_states_the_recorded_load():
    from shadowlab.harness.ledger import _load_label

    assert _load_label(None) == "not recorded"
    rec = {"cpus": 2, "load_average_before": [0.25, 0.5, 0.5], "load_average_after": [1.75, 1, 1]}
    assert _load_label(rec) == "0.25 / 1.75 (2 cores)"
