"""The hw-sim command: start a simulated bus, print its port path, serve until interrupted."""

from __future__ import annotations

import argparse
import faulthandler
import signal
import sys

from dataclasses import replace

from hw_sim.control_table import MODELS, to_shaft
from hw_sim.errors import HwSimError
from hw_sim.faults import parse_ids
from hw_sim.motion import (BUILTIN, GUIDED_HOLD_S, GUIDED_RAMP_S, GUIDED_REST_S, GUIDED_SETTLE_S, PACE,
                           OneAtATime, WithinLimits)
from hw_sim.rig_servos import RigServo, read_rig_servos

#: ``--motion guided``: each servo in turn out and back, as a person following calibrate --guided.
GUIDED = "guided"


def parse_servos(text: str, default_model: str) -> dict[int, str]:
    """'1-3:XL330-M288,4-9:XL430-W250' or '1-14' -> {id: model}; ValueError on anything else.

    Each comma-separated item is ``IDS[:MODEL]`` (IDS: ``a`` or ``a-b``); items without a model
    get ``default_model``.
    """
    servos: dict[int, str] = {}
    for item in text.split(","):
        ids_text, colon, model = item.strip().partition(":")
        model = model.strip() if colon else default_model
        if model not in MODELS:
            raise ValueError(f"unknown model {model!r} (known: {', '.join(MODELS)})")
        for i in parse_ids(ids_text):
            if i in servos:
                raise ValueError(f"servo id {i} is given twice")
            servos[i] = model
    return servos


def describe(servos: dict[int, str]) -> str:
    """{1: 'A', 2: 'A', 5: 'B'} -> '1-2: A; 5: B'."""
    by_model: dict[str, list[int]] = {}
    for i, model in sorted(servos.items()):
        by_model.setdefault(model, []).append(i)
    parts = []
    for model, ids in by_model.items():
        runs, start = [], ids[0]
        for a, b in zip(ids, ids[1:] + [None]):
            if b != a + 1:
                runs.append(f"{start}-{a}" if a != start else f"{a}")
                start = b
        parts.append(f"{','.join(runs)}: {model}")
    return "; ".join(parts)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hw-sim",
        description="Simulated Dynamixel bus on a pseudo-terminal; prints the port to open.",
    )
    parser.add_argument("--servos", default=None,
                        help="servo ids and models, e.g. 1-14, 1,2,5, 1-3:XL330-M288,4-9:XL430-W250 "
                             "or 1-6:AX-12A,7-10:MX-28 (ids without a model get --model; default "
                             "1-14); one bus carries one protocol: Protocol 1.0 models (AX, RX, "
                             "MX) and 2.0 models (X, MX(2.0), XL-320) are not mixed")
    parser.add_argument("--rig", default=None, metavar="RIG",
                        help="a puppet rig file (TOML): serve exactly its servos (ids and models); "
                             "the default motion then swings each joint across its own range "
                             "(the middle of its limits +- 0.35 x their span)")
    parser.add_argument("--model", default="XL330-M288", choices=sorted(MODELS),
                        help="servo model for ids given without one")
    parser.add_argument("--motion", default=None,
                        help=f"motion source: {', '.join(sorted(BUILTIN))}, {GUIDED} (each servo in "
                             "turn, in the rig file's order, turned 30 degrees and back the way "
                             "'puppet calibrate --guided' asks: positive, or negative where the "
                             "limits leave more room), a keyframe CSV "
                             "path, or replay:PATH (CSV, NPZ or a take of recorded ticks); "
                             "default: wave, or with --rig a swing within the rig's limits")
    parser.add_argument("--pace", type=float, default=None,
                        help=f"with --motion {GUIDED}: how quick the simulated person is, a factor "
                             f"on its timings (default 1: it rests {GUIDED_SETTLE_S:g} s from the "
                             f"host's first read, then turns each servo in {GUIDED_RAMP_S:g} s, holds "
                             f"it {GUIDED_HOLD_S:g} s, brings it back and rests {GUIDED_REST_S:g} s; "
                             f"2 is twice as quick; {PACE[0]:g}..{PACE[1]:g})")
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
    motion = args.motion
    if args.rig is not None:
        if args.servos is not None:
            print("hw-sim: give --rig or --servos, not both", file=sys.stderr)
            return 2
        try:
            rig_servos = read_rig_servos(args.rig)
        except HwSimError as exc:
            print(f"hw-sim: --rig: {exc}", file=sys.stderr)
            return 2
        servos = {s.id: s.model for s in rig_servos}
        # The rig's ticks are each servo's own; the motion sources speak shaft counts (4096 a
        # turn, 2048 the middle): the same on 4096-tick models, rescaled on 300° ones.
        rig_servos = [replace(s, zero_ticks=to_shaft(MODELS[s.model].spec, s.zero_ticks))
                      for s in rig_servos]
        if motion is None:
            motion = WithinLimits(rig_servos)
    else:
        try:
            if args.servos is not None and not args.servos.strip():
                raise ValueError("no servo ids given (e.g. 1-14, or leave --servos out for 1-14)")
            servos = parse_servos("1-14" if args.servos is None else args.servos, args.model)
        except ValueError as exc:
            print(f"hw-sim: --servos {args.servos!r}: {exc}", file=sys.stderr)
            return 2
        rig_servos = [RigServo(i, model) for i, model in sorted(servos.items())]
    if args.pace is not None and motion != GUIDED:
        print(f"hw-sim: --pace is the pace of --motion {GUIDED}; give both or neither", file=sys.stderr)
        return 2
    if motion == GUIDED:
        try:
            motion = OneAtATime.at_pace(rig_servos, 1.0 if args.pace is None else args.pace)
        except ValueError as exc:
            print(f"hw-sim: --pace {args.pace}: {exc}", file=sys.stderr)
            return 2
    if isinstance(motion, WithinLimits):
        motion_name = "within the rig's limits"
    elif isinstance(motion, OneAtATime):
        motion_name = (f"{GUIDED}: servos {', '.join(str(s.id) for s in rig_servos)} one at a time, "
                       "from the first time the host reads")
    else:
        motion_name = motion or "wave"
    try:
        server = Server(servos, motion=motion or "wave", faults=args.faults,
                        timing=args.timing, baud=args.baud, return_delay_us=args.return_delay_us,
                        echo=args.echo, strict_baud=args.strict_baud)
    except (HwSimError, ValueError) as exc:
        print(f"hw-sim: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # kill -USR1: where it is, on stderr
    try:  # a Ctrl-C as soon as the port is printed stops it as well as one later
        print(server.path, flush=True)
        print(f"hw-sim: {len(servos)} servos ({describe(servos)}) at {args.baud} baud, "
              f"motion {motion_name}; stable link {server.link}; Ctrl-C to stop", file=sys.stderr,
              flush=True)
        server.run()
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
