"""Generate the bundled scene folders: ``python -m scenes.build [--no-preview] [NAME ...]``.

Deterministic: a folder is removed and rewritten from the code of its module. Without names,
every bundled scene is built. ``preview.png`` (a low-spp render of every view) is written too
unless ``--no-preview`` is given.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from functools import partial
from pathlib import Path

from scenes import BUNDLED_DIR, city_block, cornell_box, furnace, plane_sky, street_block, urban_canyon
from scenes import urban_canyon_car, urban_canyon_field, urban_canyon_glossy, urban_canyon_misfit, urban_canyon_survey
from scenes.preview import write_preview

BUILDERS = {
    "urban_canyon": partial(urban_canyon.build, channels="rgb"),
    "urban_canyon_mono": partial(urban_canyon.build, channels="mono"),
    "cornell_box": cornell_box.build,
    "plane_sky": plane_sky.build,
    "furnace": furnace.build,
    "street_block": partial(street_block.build, buildings=2, seed=0),
    "urban_canyon_glossy": urban_canyon_glossy.build,
    "urban_canyon_field": urban_canyon_field.build,
    "city_block": city_block.build,
    "urban_canyon_survey": urban_canyon_survey.build,
    "urban_canyon_misfit": urban_canyon_misfit.build,
    "urban_canyon_car": urban_canyon_car.build,
}


def build(name: str, root: Path = BUNDLED_DIR, preview: bool = True) -> Path:
    """(Re)write scene ``name`` under ``root``; returns its folder."""
    folder = Path(root) / name
    if folder.exists():
        shutil.rmtree(folder)
    BUILDERS[name](folder)
    if preview:
        write_preview(folder)
    return folder


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"scenes to build (default: all of {', '.join(BUILDERS)})")
    parser.add_argument("--no-preview", action="store_true", help="skip preview.png")
    parser.add_argument("--root", type=Path, default=BUNDLED_DIR, help="where to write the folders")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in BUILDERS]
    if unknown:
        parser.error(f"unknown scene(s) {', '.join(unknown)}; choose from {', '.join(BUILDERS)}")
    for name in args.names or BUILDERS:
        folder = build(name, args.root, preview=not args.no_preview)
        size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
        print(f"{name}: {folder} ({size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
