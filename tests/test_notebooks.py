"""The notebooks in notebooks/ execute at CI size (jupytext + nbclient), each in a fresh
kernel started in the repository root. Select them with ``-m notebooks``.

Each notebook checks its own numbers (``assert`` cells against the reference, the
method's counters or a plain replay), so executing it without error is the test."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.py"))

pytestmark = pytest.mark.notebooks


def test_the_notebooks_are_there():
    assert {p.stem for p in NOTEBOOKS} >= {"quick_start", "cluster_hierarchy", "top_tree",
                                            "soft_shadow_grid", "compare_methods"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_at_ci_size(path, monkeypatch):
    jupytext = pytest.importorskip("jupytext")
    nbclient = pytest.importorskip("nbclient")
    import nbformat

    monkeypatch.setenv("SHADOWLAB_NOTEBOOK_SIZE", "ci")
    monkeypatch.delenv("SHADOWLAB_SWEEP_RESULTS", raising=False)
    nb = jupytext.read(path)
    assert nb.metadata["jupytext"]["text_representation"]["format_name"] == "percent"
    # The kernel must run this tree's shadowlab, not another installed copy.
    nb.cells.append(nbformat.v4.new_code_cell("import shadowlab; print(shadowlab.__file__)"))
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(ROOT)}})
    client.execute()
    printed = "".join(o.get("text", "") for o in nb.cells[-1].outputs)
    assert Path(printed.strip()).resolve() == ROOT / "shadowlab" / "__init__.py"
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert not errors
