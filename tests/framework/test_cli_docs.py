"""docs/cli.md's method option tables and the base methods' YAML files are what the option
dataclasses generate."""
import dataclasses

import pytest

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


def test_generated_yaml_files_are_current():
    """Each base method's and executor's YAML holds what its option dataclass generates
    (``python -m framework.method_yaml`` rewrites them)."""
    from framework.method_yaml import generated
    files = generated()
    assert {p.stem for p in files} == {"symbolic", "iterative", "differentiable", "serial", "dask"}
    for path, text in files.items():
        assert path.read_text() == text, f"{path.name} is stale: run python -m framework.method_yaml"


def test_defaults_round_trip_through_the_yaml():
    """``build(cls, {})`` (every field's default) equals the options built from the generated
    mapping, for every registered method's options and the Dask executor's."""
    from framework.executor_options import DaskOptions
    from framework.options import build, defaults_of
    from framework.registry import available_methods, get_method
    for cls in {get_method(n).Options for n in available_methods()} | {DaskOptions}:
        assert build(cls, defaults_of(cls)) == build(cls, {})


def test_option_without_default_is_refused():
    from framework.options import option
    with pytest.raises(TypeError, match="has no default"):
        dataclasses.make_dataclass("Bad", [("x", int, option("an option"))])
