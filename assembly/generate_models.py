"""Regenerate every committed model file under assembly/models/ (bit-identical for the same code).

Usage: python -m assembly.generate_models [--out DIR]   (or `make models`)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from assembly.gear_meshes import write_gearset_models
from assembly.panda_model import write_panda_models

MODELS_DIR = Path(__file__).resolve().parent / "models"


def generate_all(models_dir: Path = MODELS_DIR) -> list[Path]:
    """Write the Panda and the gear set under `models_dir`; return the written paths."""
    models_dir.mkdir(parents=True, exist_ok=True)
    return write_panda_models(models_dir) + write_gearset_models(models_dir)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=MODELS_DIR, help="models directory")
    out = parser.parse_args().out
    paths = generate_all(out)
    print(f"wrote {len(paths)} files under {out}")


if __name__ == "__main__":
    main()
