"""The base methods' and the executors' YAML files, generated from their option dataclasses.

An option's default lives on its dataclass field (:func:`framework.options.option`); Hydra
composes the YAML files of ``framework/conf/method`` and ``framework/conf/executor``. A base
method's file (one without a Hydra ``defaults`` list) and every executor's file are written from
the fields by :func:`text`, so the two never disagree; a preset's file (``symbolic_paper``,
``lambertian_prior``) is written by hand: it names its base and the defaults it changes.

``python -m framework.method_yaml`` rewrites the generated files; the test suite checks that each
holds what this module generates.
"""
from __future__ import annotations

import sys
from pathlib import Path

import yaml

from framework.options import defaults_of

CONF = Path(__file__).parent / "conf"


def generated() -> dict[Path, str]:
    """File -> the text it must hold, for every generated YAML file."""
    from framework.executor_options import EXECUTORS
    from framework.registry import available_methods, get_method
    out = {}
    for name in available_methods():
        path = CONF / "method" / f"{name}.yaml"
        if "defaults" not in (yaml.safe_load(path.read_text()) or {}):
            cls = get_method(name)
            out[path] = text(f"method={name}: {_first_sentence(cls, name)}", {"name": name, "tail_bounces": cls.tail_bounces},
                             cls.Options)
    for name, cls in EXECUTORS.items():
        out[CONF / "executor" / f"{name}.yaml"] = text(f"executor={name}: {_first_sentence(cls, name)}",
                                                       {"name": name}, cls)
    return out


def _first_sentence(cls, name: str) -> str:
    import re
    return re.split(r"(?<=\.)\s", " ".join((cls.__doc__ or f"{name}.").split()), maxsplit=1)[0]


def text(title: str, head: dict, cls) -> str:
    """The YAML of ``head`` then the defaults of the options dataclass ``cls``, under a comment
    saying where they come from."""
    import textwrap
    note = (f"{title} Generated from {cls.__module__}.{cls.__qualname__} by `python -m framework.method_yaml`: "
            "change a default on its field there. What each option means and allows: docs/cli.md.")
    comment = "".join(f"# {line}\n" for line in textwrap.wrap(note.replace("``", "`"), 98))
    body = {**head, **defaults_of(cls)}
    return comment + yaml.safe_dump(body, sort_keys=False, default_flow_style=False, allow_unicode=True)


def main() -> int:
    for path, content in generated().items():
        current = path.read_text() if path.exists() else None
        if current != content:
            path.write_text(content)
            print(f"wrote {path.relative_to(CONF.parents[1])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
