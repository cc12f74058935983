"""Bundled scenes in the scene-directory format (``docs/scene-format.md``).

Each bundled scene is a sub-folder ``scenes/<name>/`` holding ``scene.yaml``, ``meshes/``,
``sparse/`` and optional environment maps. The folders are (re)written deterministically by
``python -m scenes.build [NAME ...]``.
"""
from __future__ import annotations

from pathlib import Path

import framework  # noqa: F401  (a usable libLLVM for Dr.Jit before the builders import it)

#: Folder of this package: the bundled scene ``name`` lies in ``BUNDLED_DIR / name``.
BUNDLED_DIR = Path(__file__).resolve().parent


def bundled_names() -> list[str]:
    """Names of the bundled scenes present on disk (sub-folders holding a ``scene.yaml``).

    Returns
    -------
    list of str
        Sorted scene names, e.g. ``['cornell_box', 'furnace', ...]``.
    """
    return sorted(p.parent.name for p in BUNDLED_DIR.glob("*/scene.yaml"))
