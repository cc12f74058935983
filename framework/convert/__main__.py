"""``python -m framework.convert SOURCE OUT_DIR --sparse DIR [--images DIR] [--masks DIR] --emitters FILE
[--group material|object|semantic] [--kernels SEGMENT=k1,k2 ...] [--default-kernels k1,k2]``.

Bad input prints one line ``error: <what is wrong and the fix>`` on stderr and exits with status 2,
writing nothing; warnings (degenerate polygons dropped, labels no face uses, materials without
faces, glTF float32 positions at survey coordinates) are lines ``warning: ...`` on stderr. On success it prints a short summary on stdout.
"""
from __future__ import annotations

import argparse
import sys

import framework  # noqa: F401  (a usable libLLVM for Dr.Jit before Mitsuba loads)
from framework.errors import UserError


class _Parser(argparse.ArgumentParser):
    """argparse, with its errors as one line (``error: ...``, status 2) and no usage block."""

    def error(self, message: str):
        print(f"error: {message}; see python -m framework.convert --help", file=sys.stderr)
        raise SystemExit(2)


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m framework.convert",
                description="Convert a labelled mesh (OBJ, glTF/GLB, labelled PLY) or a CityJSON city model "
                            "into a scene folder (docs/convert.md).")
    p.add_argument("source", metavar="SOURCE", help=".obj, .gltf/.glb, .ply (+ <stem>.labels.yaml) or CityJSON .json")
    p.add_argument("out_dir", metavar="OUT_DIR", help="the scene folder to write (new, or empty)")
    p.add_argument("--sparse", required=True, metavar="DIR", help="COLMAP model in the frame of SOURCE")
    p.add_argument("--images", metavar="DIR", help="photographs, copied to OUT_DIR/images")
    p.add_argument("--masks", metavar="DIR", help="masks, copied to OUT_DIR/masks")
    p.add_argument("--emitters", required=True, metavar="FILE",
                   help="YAML file with an 'emitters:' list as in scene.yaml (and optionally 'channels:')")
    p.add_argument("--group", choices=("material", "object", "semantic"),
                   help="segments from materials, objects, or (CityJSON) object and surface type; "
                        "default: material, semantic for CityJSON")
    p.add_argument("--kernels", nargs="+", default=[], metavar="SEGMENT=k1,k2",
                   help="kernels of the segments SEGMENT names: a segment's very name (matched first), or a "
                        "shell pattern such as '*/Window' ([[] matches a literal '[')")
    p.add_argument("--default-kernels", default="diffuse", metavar="k1,k2",
                   help="kernels of the other segments (default diffuse; CityJSON windows: diffuse,specular)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    kernels = {}
    try:
        for item in args.kernels:
            name, sep, ks = item.partition("=")
            if not sep or not name or not ks:
                raise UserError(f"--kernels {item}: write SEGMENT=k1,k2 (e.g. '*/Window=diffuse,specular')")
            kernels[name] = ks
        from framework.convert.convert import convert
        done = convert(args.source, args.out_dir, sparse=args.sparse, emitters=args.emitters, images=args.images,
                       masks=args.masks, group=args.group, kernels=kernels, default_kernels=args.default_kernels)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    for line in done.warnings:
        print(f"warning: {line}", file=sys.stderr)
    print(f"{done.folder}: {len(done.segments)} segments, {done.triangles} triangles, {done.views} views, "
          f"origin [{', '.join(f'{x:.3f}' for x in done.origin)}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
