"""The `goflow` command: a thin dispatcher over the packages (nothing imports this module)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _cmd_demo(args: argparse.Namespace) -> int:
    if not args.scripted:
        print("goflow demo: only the scripted assembly exists so far; run `goflow demo --scripted`",
              file=sys.stderr)
        return 2
    from assembly.demo import AssemblyConfig, format_summary, run_assembly
    from assembly.station import make_meshcat

    meshcat = None
    if args.meshcat or args.record:
        meshcat = make_meshcat()
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    summary = run_assembly(AssemblyConfig(), meshcat=meshcat,
                           record=Path(args.record) if args.record else None,
                           realtime=args.meshcat and not args.record, progress=not args.quiet)
    print(format_summary(summary))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(summary, indent=2))
    if args.meshcat and not args.record:
        input("Press Enter to close Meshcat...") if sys.stdin.isatty() else None
    return 1 if "sim_error" in summary else 0


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="goflow", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the gearbox assembly")
    demo.add_argument("--scripted", action="store_true",
                      help="scripted pick-and-insert of all three gears")
    demo.add_argument("--meshcat", action="store_true", help="show it live in Meshcat (localhost)")
    demo.add_argument("--record", metavar="FILE.html", help="save a Meshcat recording")
    demo.add_argument("--json", metavar="PATH", help="write the per-gear summary as JSON")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
