"""The ``seaice`` command. Thin: parses arguments, calls the library, prints, exits with a clear message."""

import argparse
import sys

from seaice_jax import __version__
from seaice_jax.errors import SeaiceError


def _demo(args) -> int:
    from seaice_jax.demo import run_demo

    print(run_demo(args.out).summary)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="seaice", description="Sea-ice mapping and drift from radar strips and "
                                     "satellite images (seaice_jax).")
    parser.add_argument("--version", action="version", version=f"seaice_jax {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="run the main job on the built-in scenario")
    demo.add_argument("--out", default="seaice-demo", help="output folder (default: ./seaice-demo)")
    demo.set_defaults(run=_demo)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (SeaiceError, ValueError, OSError) as error:
        print(f"seaice {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
