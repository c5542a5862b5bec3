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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "demo":
        print("jaxrecog demo: nothing to run yet")
        return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
