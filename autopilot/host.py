"""Several vehicles' autopilots in one process: ``python -m autopilot.host -- ARGS -- ARGS ...``, each ARGS one
autopilot's command line (``python -m autopilot ARGS``), as ``quadsitl up --vehicles N --hosted`` starts them.

Each vehicle is the same :class:`autopilot.process.Autopilot` a process of its own runs, with its own sockets (the
plant's, its ground-station and offboard links), MAVLink identity, parameters, commander and failsafes, and its own
Zenoh session: from outside, the fleet looks as N processes do (PX4's multi-vehicle SITL, one instance a vehicle).
The vehicles fly in groups, a thread each, as many as the cores but one (:func:`autopilot.group.group_threads`;
:class:`autopilot.group.Group`: one ``epoll_wait`` on the group's plant sockets, the datagrams served in compiled code
that does not hold Python's lock, so the other groups fly meanwhile); a vehicle that cannot be grouped flies its own
loop (:meth:`Autopilot.run`) in a thread of its own, waiting in :func:`autopilot.plant_loop.serve_unlocked`. They share
one interpreter, one compiler and the compiled code: a fleet's memory is its vehicles' state, not N interpreters
(docs/fleets.md#hosted-autopilots).

The process says it is ready (:func:`quadsitl.process_util.say_ready`) once every vehicle has sent its first heartbeat,
and stops every vehicle on SIGINT or SIGTERM. A vehicle whose loop fails ends the process (exit status 1), as the
end of its own process would end ``quadsitl up``: nothing flies on without a supervisor knowing.
"""

from __future__ import annotations

import sys
import threading
import traceback
from collections.abc import Callable, Sequence

from autopilot.group import Group, groups_of
from autopilot.process import REFUSED, Autopilot, build_parser, open_autopilot, refusal
from quadsitl.jit import favour_compile_time
from quadsitl.process_util import say_ready, start_process

PROG = "python -m autopilot.host"
JOIN_S = 5.0  # [s] wall: how long a vehicle's loop has to end once told to stop (it checks every HOUSEKEEPING)


def vehicles_of(argv: Sequence[str]) -> list[list[str]]:
    """The autopilots' command lines in ``argv`` (``-- ARGS -- ARGS ...``), or a ValueError saying what is wrong."""
    if not argv or argv[0] != "--":
        raise ValueError("expected -- ARGS [-- ARGS ...]: each ARGS one autopilot's options (python -m autopilot ARGS)")
    groups: list[list[str]] = []
    for word in argv:
        if word == "--":
            groups.append([])
        else:
            groups[-1].append(word)
    if any(not g for g in groups):
        raise ValueError("an empty autopilot command line between two --")
    return groups


class Readiness:
    """Says the process is ready (:func:`say_ready`) when the last of ``count`` vehicles has said so."""

    def __init__(self, count: int) -> None:
        self.left = count
        self.lock = threading.Lock()

    def one(self) -> None:
        with self.lock:
            self.left -= 1
            if self.left == 0:
                say_ready()


def main(argv: Sequence[str] | None = None) -> int:
    start_process()
    favour_compile_time()  # compiles at -O2: a first run's wait (docs/performance.md#compiling-on-first-run)
    try:
        lines = vehicles_of(sys.argv[1:] if argv is None else argv)
    except ValueError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    parser = build_parser()
    every = [parser.parse_args(line) for line in lines]  # all refused or none, before any vehicle opens a socket
    aps: list[Autopilot] = []
    try:
        for args in every:
            aps.append(open_autopilot(args, unlocked=True))
    except REFUSED as exc:
        print(refusal(PROG, exc), file=sys.stderr)
        for ap in aps:
            ap.close()
        return 2
    stop, ready, failed = threading.Event(), Readiness(len(aps)), []
    groups, alone = groups_of(aps)

    def fly(label: str, run: Callable[[threading.Event, Callable[[], None]], None]) -> None:
        try:
            run(stop, ready.one)
        except BaseException as exc:  # the loop ended: every vehicle stops, and the supervisor hears of it
            failed.append(label)
            print(f"{label}: error: its loop failed: {exc!r}", file=sys.stderr, flush=True)
            traceback.print_exc()
            stop.set()

    flown = [(", ".join(ap.label for ap in g), Group(g).run) for g in groups] + [(ap.label, ap.run) for ap in alone]
    threads = [threading.Thread(target=fly, args=(label, run), name=label, daemon=True) for label, run in flown]
    try:
        for t in threads:
            t.start()
        while not stop.wait(0.5):  # SIGINT and SIGTERM arrive in this thread (KeyboardInterrupt)
            pass
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        for t in threads:
            t.join(JOIN_S)
        for ap in aps:
            ap.close()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
