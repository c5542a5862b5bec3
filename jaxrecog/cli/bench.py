"""``jaxrecog bench``: run the benchmark scripts and merge their JSON."""

from __future__ import annotations

import json
from pathlib import Path

from .._files import check_output_folder, write_text
from ..problems import problem_message
from .._progress import bar
from ._bench_runner import find_scripts, headline, run_all
from ._common import CLIError, print_table
from ._options import positive

NAME = "bench"
ORDER = 70
HELP = "run the benchmark scripts and merge their JSON"
DESCRIPTION = ("Run every benchmarks/bench_*.py script (each with --out FILE.json), merge the\n"
               "results into one JSON file and print a summary table.")

#: benchmarks/ of a source checkout (next to the jaxrecog package folder)
_BENCHMARKS = Path(__file__).resolve().parent.parent.parent / "benchmarks"


def add_arguments(p) -> None:
    p.add_argument("--out", default="out/bench", metavar="FOLDER", help="folder of the JSON files")
    p.add_argument("--benchmarks", metavar="FOLDER",
                   help="folder of the scripts (default: benchmarks/ next to the package)")
    p.add_argument("--only", nargs="+", metavar="NAME", help="run only these (e.g. render training)")
    p.add_argument("--timeout", type=positive, default=1800, help="seconds allowed per script")


def run(args) -> int:
    folder = Path(args.benchmarks) if args.benchmarks else _BENCHMARKS
    scripts = find_scripts(folder, args.only)
    if not scripts:
        raise CLIError(f"no benchmark scripts (bench_*.py) found in {folder}"
                       + (f" matching {' '.join(args.only)}" if args.only else ""))
    out = check_output_folder(args.out, "--out folder")
    with bar(len(scripts), "bench", "script") as b:
        outcomes = run_all(scripts, out, args.timeout, progress=b.update)
    merged = {o.name: o.record for o in outcomes}
    merged_path = out / "bench.json"
    write_text(merged_path, json.dumps(merged, indent=2) + "\n", "benchmark summary")
    print_table(["benchmark", "status", "wall s", "numbers"],
                [(o.name, o.status, f"{o.wall_s:.1f}", headline(o.record)) for o in outcomes])
    print(f"wrote {merged_path}")
    failed = [o.name for o in outcomes if o.status != "ok"]
    if failed:
        raise CLIError(problem_message(f"benchmark(s) failed (see {merged_path})", failed))
    return 0
