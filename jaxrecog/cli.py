"""The ``jaxrecog`` command.  Subcommands are added as their pieces land."""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxrecog", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="what `make demo` runs")
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    return parser


def _demo(out: str) -> int:
    """Until the rig and recognizer land: generate a small database, train a DB2
    model, save it and print its summary."""
    from pathlib import Path

    from .database import load_database
    from .modelfile import load_model, save_model
    from .testing import write_synthetic_database
    from .train import train_model

    folder = Path(out)
    db_dir = write_synthetic_database(folder / "database", positions=(8, 3), n_objects=4,
                                      n_poses=4, image_shape=(60, 80))
    db = load_database(db_dir)
    print(f"database {db_dir}: {db.n_rows} images, positions {db.positions}, "
          f"{db.n_objects} objects x {db.n_poses} poses")
    model, info = train_model(db, kind="DB2", n_components=10, return_info=True)
    path = save_model(folder / "model_db2.npz", model, training=info.params,
                      manifest_sha256=info.manifest_sha256)
    print(f"trained DB2 in {info.seconds:.1f} s -> {path}")
    print(load_model(path).summary())
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "demo":
        return _demo(args.out)
    return 2


if __name__ == "__main__":
    sys.exit(main())
