import pytest
"""docs/cli.md's method option tables are what the option dataclasses generate."""
from framework import cli_docs
from framework.registry import available_methods


def test_every_method_has_a_generated_table():
    assert cli_docs.documented() == set(available_methods())


@pytest.mark.slow
def test_tables_match_the_option_dataclasses():
    """Regenerate with ``python -m framework.cli_docs`` after changing an option or a default."""
    text = cli_docs.DOC.read_text()
    assert cli_docs.render(text) == text


@pytest.mark.slow
def test_preset_tables_list_what_differs():
    paper = {row[0] for row in cli_docs.rows("symbolic_paper")}
    assert paper == {row[0] for row in cli_docs.rows("symbolic")}
    assert "`method.refine` | integer in [0, 8] | 0 |" in cli_docs.table("symbolic_paper")
    assert "method.prob_floor" not in cli_docs.table("symbolic_paper")
