"""Regenerate every committed model file under assembly/models/ (byte-identical on any machine).

Usage: python -m assembly.generate_models [--out DIR] [--check]   (or `make models`)

Every mesh is written in the canonical vertex and face order of
`assembly.gear_meshes.canonical_mesh` (values rounded to the written precision first), so the files
do not depend on the CPU or on the order in which trimesh or numpy's sorts produce vertices and
faces. `--check` regenerates into a temporary folder and lists what differs from DIR instead of
writing there.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from assembly.gear_meshes import canonical_obj_geometry, write_gearset_models
from assembly.panda_model import write_panda_models

__all__ = ["MODELS_DIR", "generate_all", "model_differences"]

MODELS_DIR = Path(__file__).resolve().parent / "models"


def generate_all(models_dir: Path = MODELS_DIR) -> list[Path]:
    """Write the Panda and the gear set.

    Arguments:
        models_dir: the models folder (created if missing); files go to its `panda/` and `gearset/`.

    Returns:
        The paths written.
    """
    models_dir.mkdir(parents=True, exist_ok=True)
    return write_panda_models(models_dir) + write_gearset_models(models_dir)


def model_differences(fresh_dir: Path, committed_dir: Path) -> list[str]:
    """What differs between two model folders, one line per finding, most telling first.

    Arguments:
        fresh_dir: a freshly generated folder (e.g. `generate_all(tmp)`, or its `panda/` subfolder).
        committed_dir: the folder to compare with, laid out alike.

    Returns:
        Lines for: files present in only one folder; OBJ files whose geometry differs (their
        `canonical_obj_geometry`, i.e. the vertex and face sets whatever their order); then files
        whose bytes differ although their geometry is the same (a writer that is not canonical).
        Empty when the folders hold the same bytes.
    """
    fresh = {p.relative_to(fresh_dir) for p in fresh_dir.rglob("*") if p.is_file()}
    committed = {p.relative_to(committed_dir) for p in committed_dir.rglob("*") if p.is_file()}
    lines = [f"only in {fresh_dir}: {rel}" for rel in sorted(fresh - committed)]
    lines += [f"only in {committed_dir}: {rel}" for rel in sorted(committed - fresh)]
    byte_lines = []
    for rel in sorted(fresh & committed):
        a, b = fresh_dir / rel, committed_dir / rel
        if rel.suffix == ".obj" and not _same_obj_geometry(a, b):
            lines.append(f"geometry differs: {rel}")
        elif a.read_bytes() != b.read_bytes():
            note = " (same geometry)" if rel.suffix == ".obj" else ""
            byte_lines.append(f"bytes differ{note}: {rel}")
    return lines + byte_lines


def _same_obj_geometry(a: Path, b: Path) -> bool:
    """Whether two OBJ files hold the same vertex and face sets (`canonical_obj_geometry`)."""
    (rows_a, faces_a), (rows_b, faces_b) = canonical_obj_geometry(a), canonical_obj_geometry(b)
    return np.array_equal(rows_a, rows_b) and np.array_equal(faces_a, faces_b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=MODELS_DIR, help="models directory")
    parser.add_argument(
        "--check", action="store_true", help="regenerate into a temporary folder and list differences from --out"
    )
    args = parser.parse_args()
    if not args.check:
        paths = generate_all(args.out)
        print(f"wrote {len(paths)} files under {args.out}")
        return
    with tempfile.TemporaryDirectory() as tmp:
        generate_all(Path(tmp))
        differences = model_differences(Path(tmp), args.out)
    print("\n".join(differences) or f"{args.out} is up to date")
    sys.exit(1 if differences else 0)


if __name__ == "__main__":
    main()
