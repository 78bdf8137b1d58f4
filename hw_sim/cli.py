"""The hw-sim command: start a simulated bus and print its port path."""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hw-sim",
        description="Simulated Dynamixel bus on a pseudo-terminal; prints the port to open.",
    )
    parser.add_argument("--servos", default="1-14", help="servo ids, e.g. 1-14 or 1,2,5")
    parser.add_argument("--model", default="XL330-M288", help="servo model")
    parser.add_argument("--motion", default="wave", help="motion source")
    parser.add_argument("--faults", default=None, help="fault schedule file")
    return parser


def main(argv: list[str] | None = None) -> int:
    build_parser().parse_args(argv)
    print("hw-sim: the bus server is not built yet (issue #4).", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
