"""``jaxrecog recipes``: the named training and stop-rule recipes."""

from __future__ import annotations

from ..recipes import DEFAULT_RECIPE, RECIPES, get_recipe
from ._common import UsageError

NAME = "recipes"
ORDER = 25
HELP = "list the training and stop-rule recipes (train --recipe)"
DESCRIPTION = ("List the recipes `jaxrecog train --recipe NAME` trains by, each with its parts:\n"
               "likelihood, interpolated views, view jitter, calibration, shift range and stop rule.\n"
               "A model file records its recipe; recognize and experiment --rig dataset: take the\n"
               f"stop rule from it.  The default is {DEFAULT_RECIPE}; 'thesis' reproduces the thesis.")


def add_arguments(p) -> None:
    p.add_argument("name", nargs="?", metavar="NAME", help="show one recipe (default: all)")


def run(args) -> int:
    try:
        chosen = [get_recipe(args.name)] if args.name else list(RECIPES.values())
    except ValueError as e:
        raise UsageError(str(e)) from None
    for i, r in enumerate(chosen):
        if i:
            print()
        default = " (default)" if r.name == DEFAULT_RECIPE else ""
        print(f"{r.name}{default}, version {r.version}: {r.summary}")
        for line in r.describe():
            print(f"  {line}")
    return 0
