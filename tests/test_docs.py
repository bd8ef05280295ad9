"""The docs stay true to the code: counter table, methods, config keys."""

from pathlib import Path

from shadowlab import methods
from shadowlab.counters import COUNTERS, markdown_table

ROOT = Path(__file__).resolve().parent.parent


def test_counter_doc_is_generated_from_the_table():
    text = (ROOT / "docs" / "counters.md").read_text()
    assert markdown_table() in text, "regenerate: python -m shadowlab.counters > docs/counters.md"


def test_every_counter_name_is_unique_and_documented():
    assert len(COUNTERS) == len({c.name for c in COUNTERS.values()})
    for c in COUNTERS.values():
        assert c.kind in ("int", "float", "map", "array") and c.meaning


def test_readme_lists_every_method():
    readme = (ROOT / "README.md").read_text()
    for name in methods.names():
        assert f"`{name}`" in readme, f"README method table lacks {name}"


def test_readme_has_exactly_two_setup_commands_and_ci_uses_the_test_one():
    readme = (ROOT / "README.md").read_text()
    setup = readme.split("## Set up", 1)[1].split("\n## ", 1)[0]
    blocks = [b.split("```", 1)[0].strip() for b in setup.split("```bash")[1:]]
    assert len(blocks) == 2
    assert "shadowlab run" in blocks[0] and "pytest" in blocks[1]
    assert blocks[1] in (ROOT / ".ci" / "run").read_text()
