"""The hw-sim command: start a simulated bus, print its port path, serve until interrupted."""

from __future__ import annotations

import argparse
import signal
import sys

from hw_sim.control_table import MODELS
from hw_sim.errors import HwSimError
from hw_sim.faults import parse_ids
from hw_sim.motion import BUILTIN


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hw-sim",
        description="Simulated Dynamixel bus on a pseudo-terminal; prints the port to open.",
    )
    parser.add_argument("--servos", default="1-14", help="servo ids, e.g. 1-14 or 1,2,5")
    parser.add_argument("--model", default="XL330-M288", choices=sorted(MODELS),
                        help="servo model")
    parser.add_argument("--motion", default="wave",
                        help=f"motion source: {', '.join(sorted(BUILTIN))}, a keyframe CSV "
                             "path, or replay:PATH (CSV or NPZ of recorded ticks)")
    parser.add_argument("--faults", default=None, help="fault schedule file")
    parser.add_argument("--baud", type=int, default=1_000_000, help="bus baud rate (bit/s)")
    parser.add_argument("--timing", action="store_true",
                        help="model wire time: return delay + byte time at --baud")
    parser.add_argument("--return-delay-us", type=int, default=None,
                        help="Return Delay Time in us (default: the model's 500 us)")
    parser.add_argument("--echo", action="store_true", help="half-duplex echo of instructions")
    parser.add_argument("--strict-baud", action="store_true",
                        help="servos answer only when the port's speed matches their Baud Rate")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from hw_sim.server import Server  # after parsing: --help stays instant
    try:
        ids = parse_ids(args.servos)
    except ValueError as exc:
        print(f"hw-sim: --servos {args.servos!r}: {exc}", file=sys.stderr)
        return 2
    try:
        server = Server({i: args.model for i in ids}, motion=args.motion, faults=args.faults,
                        timing=args.timing, baud=args.baud, return_delay_us=args.return_delay_us,
                        echo=args.echo, strict_baud=args.strict_baud)
    except (HwSimError, ValueError) as exc:
        print(f"hw-sim: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    print(server.path, flush=True)
    print(f"hw-sim: {len(ids)} x {args.model} (ids {args.servos}) at {args.baud} baud, "
          f"motion {args.motion}; stable link {server.link}; Ctrl-C to stop", file=sys.stderr,
          flush=True)
    try:
        server.run()
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
