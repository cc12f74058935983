"""docs/cli.md's method option tables, generated from the methods' option dataclasses.

Each registered method's ``Options`` (:mod:`framework.options`) gives the rows: the override,
what its check allows, the default of the method's YAML and the field's description. A preset
(a method whose YAML derives from another's) lists only the options whose default differs.

``python -m framework.cli_docs`` rewrites the tables between the markers
``<!-- options: NAME -->`` and ``<!-- /options -->`` of docs/cli.md; the test suite checks that
the file holds what this module generates.
"""
from __future__ import annotations

import sys
from pathlib import Path

from framework.config import method_defaults
from framework.options import option_rows
from framework.registry import available_methods, get_method

DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"
HEADER = "| option | type, allowed values | default | meaning |\n|---|---|---|---|\n"
TAIL_ROW = ("method.tail_bounces", "integer in [0, 16]",
            "T when `render.tail_bounces=auto`: reflections traced beyond N_max (the symbolic pass weights "
            "them by the guesses; the baselines render `max_depth = N_max + T + 1`)")


def rows(name: str) -> list[tuple[str, str, str, str]]:
    """The option rows of method ``name``, ``method.tail_bounces`` last where its YAML has it."""
    defaults = method_defaults(name)
    out = option_rows(get_method(name).Options, defaults)
    if "tail_bounces" in defaults:
        key, allowed, meaning = TAIL_ROW
        out.append((key, allowed, str(defaults.tail_bounces), meaning))
    return out


def base_of(name: str) -> str | None:
    """The method whose YAML ``name``'s derives from (Hydra defaults list), if any."""
    import yaml
    conf = Path(__file__).parent / "conf" / "method" / f"{name}.yaml"
    defaults = yaml.safe_load(conf.read_text()).get("defaults", [])
    bases = [d for d in defaults if isinstance(d, str) and d != "_self_"]
    return bases[0] if bases else None


def table(name: str) -> str:
    """The markdown table of method ``name`` (a preset: the rows differing from its base)."""
    own, base = rows(name), base_of(name)
    if base is not None:
        theirs = {r[0]: r[2] for r in rows(base)}
        own = [r for r in own if theirs.get(r[0]) != r[2]]
    return HEADER + "".join(f"| `{k}` | {a} | {d} | {m} |\n" for k, a, d, m in own)


def render(text: str) -> str:
    """``text`` (docs/cli.md) with every marked table regenerated."""
    out, pos = [], 0
    while True:
        start = text.find("<!-- options: ", pos)
        if start < 0:
            return "".join(out) + text[pos:]
        head_end = text.index("-->", start) + 3
        name = text[start + len("<!-- options: "):head_end - 3].strip()
        end = text.index("<!-- /options -->", head_end)
        out += [text[pos:head_end], "\n", table(name)]
        pos = end
        out.append("")


def documented() -> set[str]:
    """The methods docs/cli.md has a marked table for."""
    text = DOC.read_text()
    return {text[i + len("<!-- options: "):text.index("-->", i)].strip()
            for i in range(len(text)) if text.startswith("<!-- options: ", i)}


def main() -> int:
    missing = sorted(set(available_methods()) - documented())
    if missing:
        print(f"error: docs/cli.md has no '<!-- options: NAME -->' table for {', '.join(missing)}", file=sys.stderr)
        return 2
    DOC.write_text(render(DOC.read_text()))
    return 0


if __name__ == "__main__":
    sys.exit(main())

