"""``sea-daemon watch [--state-dir DIR | --socket PATH]``: the live estimate, for a person at the exoskeleton.

Subscribes to the running daemon's publication (:mod:`sea_daemon.client`; the socket named in
``DIR/sea-daemon.pid``, or ``--socket``) and draws, in the terminal, per joint the last
``--window`` seconds of the estimated active human torque τ̂_h,act with its band τ̂ ± ρ_k, the
assistance the assist controller adds, and marks where the estimate was not valid; above the
plot the current values, the validity, the latched fault (in red) and the assist state.
``--plain`` prints one line per refresh instead (logs, serial consoles, tests).

Started before the daemon, it waits for one to publish in the state directory (or on
``--socket``), says so on stderr, and shows the run as soon as it starts; ``--timeout`` bounds
that wait (exit 2 when no daemon came).  While the daemon is silent or restarting it says so and
keeps waiting.  Runs until Ctrl-C (exit 0), or ``--frames`` refreshes.
"""
from __future__ import annotations

import json
import logging
import math
import os
import shutil
import sys
import time
from collections import deque
from pathlib import Path

from sea_daemon.client import FLAG_ASSIST_DRY_RUN, FLAG_ASSIST_ENGAGED, FLAG_ASSIST_ON, Subscriber, default_socket
from sea_daemon.errors import InputError

DESCRIPTION = __doc__
log = logging.getLogger("sea_daemon.watch")
#: seconds between two looks for a daemon that has not started yet
POLL_S = 0.2

BAND, EST, ASSIST, INVALID, AXIS = "░", "●", "a", "×", "─"


def add_arguments(p) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--state-dir", "--log-dir", dest="state_dir", metavar="DIR", default=None,
                   help="the running daemon's state directory (its sea-daemon.pid names the socket)")
    g.add_argument("--socket", metavar="PATH", default=None, help="the daemon's publication socket")
    p.add_argument("--window", type=float, default=10.0, help="seconds of history shown (default 10, at most 3600)")
    p.add_argument("--refresh", type=float, default=0.1, help="seconds between redraws (default 0.1, at most 60)")
    p.add_argument("--range", dest="y_range", type=float, default=None,
                   help="torque axis ±RANGE [N m] (default: the data's, at least ±1)")
    p.add_argument("--height", type=int, default=11, help="plot rows per joint (default 11; 5-200)")
    p.add_argument("--frames", type=int, default=None, help="stop after this many refreshes")
    p.add_argument("--plain", action="store_true", help="one text line per refresh, no terminal drawing")
    p.add_argument("--timeout", type=float, default=None, metavar="SECONDS",
                   help="wait at most this long for a daemon to start publishing (default: until Ctrl-C)")


def socket_of(args) -> Path:
    """The socket to subscribe to: ``--socket``, else the one the state directory's pid file
    names, else ``DIR/sea-daemon.sock``."""
    if args.socket:
        return Path(args.socket)
    d = Path(args.state_dir or ".")
    try:
        info = json.loads((d / "sea-daemon.pid").read_text())
        if info.get("socket"):
            return Path(info["socket"])
    except (OSError, ValueError, AttributeError):
        pass
    return default_socket(d)


def find_socket(args, waited: float | None = None) -> Path:
    """The socket of a daemon that publishes now; InputError when there is none (``waited``:
    the seconds of ``--timeout`` waited for one, said in the message)."""
    sock = socket_of(args)
    if not sock.exists():
        d = Path(args.state_dir or ".")
        where = f"on {sock}" if args.socket else f"in {d}"
        after = "" if waited is None else f" within --timeout {waited:g} s"
        what = "" if args.socket else f": neither {d / 'sea-daemon.pid'} nor {sock}"
        raise InputError(f"no sea-daemon publishes {where}{after}{what} "
                         "(give the --state-dir / --log-dir the daemon runs with, or --socket)")
    return sock


def wait_for_daemon(args, timeout: float | None, poll: float = POLL_S) -> tuple[Path, Subscriber]:
    """The socket and a subscription to it, once a daemon publishes there; until then one
    message on stderr and a look every ``poll`` seconds.  InputError after ``timeout`` seconds
    without one (None: no limit)."""
    deadline = None if timeout is None else time.monotonic() + timeout
    said = False
    while True:
        last = deadline is not None and time.monotonic() >= deadline
        sock = find_socket(args, timeout if last else None) if last else socket_of(args)
        if len(os.fsencode(str(sock))) >= 108:
            return sock, Subscriber(sock)                # refused with its own one-line reason
        try:
            sub = Subscriber(sock)
        except InputError:                                # no socket, or nobody listens on it (yet, any more)
            if last:
                raise InputError(f"no sea-daemon publishes on {sock} within --timeout {timeout:g} s (a socket "
                                 "file, no daemon behind it; give the --state-dir / --log-dir of a running "
                                 "daemon, or --socket)") from None
        else:
            if said:
                log.info("sea-daemon watch: a daemon publishes on %s", sock)
            return sock, sub
        if not said:
            where = args.socket or (args.state_dir or ".")
            log.info("sea-daemon watch: waiting for a daemon in %s … (%s; Ctrl-C to stop)", where,
                     "no limit" if timeout is None else f"at most {timeout:g} s")
            said = True
        time.sleep(poll if deadline is None else max(0.0, min(poll, deadline - time.monotonic())))


def engaged_where(s) -> str:
    """Which joints of sample ``s`` the assistance is engaged on, for the status line: the joints
    whose τ_assist ≠ 0 (any number of joints), "on some joint" when the flags say engaged and no
    joint's τ_assist names it, nothing for one joint."""
    if s.joints == 1:
        return ""
    on = [str(j + 1) for j, e in enumerate(s.engaged) if e]
    return f" (joint{'s' if len(on) > 1 else ''} {', '.join(on)})" if on else " (on some joint)"


#: the longest history shown and the longest time between redraws [s], the plot's rows per joint
MAX_WINDOW_S, MAX_REFRESH_S, MIN_HEIGHT, MAX_HEIGHT = 3600.0, 60.0, 5, 200


class View:
    """The history of the last ``window`` seconds and its drawing."""

    def __init__(self, window: float, height: int, y_range: float | None):
        self.window, self.height, self.y_range = window, max(MIN_HEIGHT, height), y_range
        self.hist: deque = deque()
        self.last = None
        self.last_wall = 0.0

    def add(self, s) -> None:
        if self.last is not None and s.t < self.last.t:       # the daemon restarted: new history
            self.hist.clear()
        self.hist.append(s)
        self.last = s
        self.last_wall = time.monotonic()
        while self.hist and self.hist[0].t < s.t - self.window:
            self.hist.popleft()

    def status(self, sock: Path, sub) -> list[str]:
        s = self.last
        if s is None:
            return [f"sea-daemon watch  {sock}: waiting for the daemon's first sample …"]
        silent = time.monotonic() - self.last_wall
        fault = "none" if not s.fault else f"\x1b[1;31m{s.fault_name} — torque zero, reset needed\x1b[0m"
        assist = ("off" if not s.flags & FLAG_ASSIST_ON else
                  ("dry run (not commanded)" if s.flags & FLAG_ASSIST_DRY_RUN else "on")
                  + (", engaged" + engaged_where(s) if s.flags & FLAG_ASSIST_ENGAGED else ", idle"))
        head = (f"sea-daemon watch  {sock}   cycle {s.cycle}   t {s.t:.2f} s   fault: {fault}   "
                f"assist: {assist}   received {sub.received}, missed {sub.missed}, rejected {sub.rejected}")
        if silent > 1.0:
            head += f"   \x1b[33m(no data for {silent:.0f} s)\x1b[0m"
        return [head]

    def joint_lines(self, j: int, width: int) -> list[str]:
        s = self.last
        hat, rho, ok = s.tau_h_act_hat[j], s.tau_h_act_bound[j], s.valid[j]
        rho_txt = f"{rho:.3f} N m" if math.isfinite(rho) else "inf"
        state = "\x1b[32mvalid\x1b[0m" if ok else "\x1b[31mNOT VALID\x1b[0m"
        head = (f"joint {j + 1}  τ̂_h,act {hat:+7.3f} N m   ρ_k {rho_txt:>10}   {state}   "
                f"τ_assist {s.tau_assist[j]:+6.3f} N m   τ_m {s.tau_m[j]:+6.3f} N m   q {math.degrees(s.q[j]):6.1f}°")
        cols = max(10, width - 9)
        t_end = s.t
        t0 = t_end - self.window
        bins: list = [None] * cols
        for x in self.hist:
            c = int((x.t - t0) / self.window * (cols - 1) + 0.5)
            if 0 <= c < cols:
                bins[c] = x
        if self.y_range:
            ymax = self.y_range
        else:
            ymax = 1.0
            for x in self.hist:
                b = x.tau_h_act_bound[j]
                v = abs(x.tau_h_act_hat[j]) + (b if math.isfinite(b) else 0.0)
                ymax = max(ymax, v, abs(x.tau_assist[j]))
            ymax = math.ceil(ymax)
        h = self.height
        grid = [[" "] * cols for _ in range(h)]

        def row(v: float) -> int:
            r = int(round((ymax - v) / (2 * ymax) * (h - 1)))
            return min(h - 1, max(0, r))
        zero = row(0.0)
        for c in range(cols):
            grid[zero][c] = AXIS
        for c, x in enumerate(bins):
            if x is None:
                continue
            b = x.tau_h_act_bound[j]
            if not x.valid[j] or not math.isfinite(b):
                grid[zero][c] = INVALID
                continue
            lo, hi = row(x.tau_h_act_hat[j] + b), row(x.tau_h_act_hat[j] - b)
            for r in range(lo, hi + 1):
                grid[r][c] = BAND
            if x.tau_assist[j] != 0.0:
                grid[row(x.tau_assist[j])][c] = ASSIST
            grid[row(x.tau_h_act_hat[j])][c] = EST
        lines = [head]
        for r in range(h):
            label = f"{ymax:+.1f}" if r == 0 else f"{-ymax:+.1f}" if r == h - 1 else "0" if r == zero else ""
            lines.append(f"{label:>6} │" + "".join(grid[r]))
        lines.append(" " * 8 + f"-{self.window:g} s".ljust(cols - 3) + "now")
        return lines

    def legend(self) -> str:
        return (f"{EST} τ̂_h,act   {BAND} τ̂ ± ρ_k (the published bound)   {ASSIST} assistance   "
                f"{INVALID} not valid (start-up, fault)   [N m]")

    def plain(self) -> str:
        s = self.last
        if s is None:
            return "waiting for the daemon"

        def f(v):
            return ",".join(f"{x:+.4f}" if math.isfinite(x) else "inf" for x in v)
        return (f"cycle {s.cycle} t {s.t:.3f} fault {s.fault_name} valid {','.join(str(int(v)) for v in s.valid)} "
                f"tau_h_act_hat {f(s.tau_h_act_hat)} tau_h_act_bound {f(s.tau_h_act_bound)} "
                f"tau_assist {f(s.tau_assist)} flags {s.flags}")


def run(args) -> int:
    for name, value, most in (("--window", args.window, MAX_WINDOW_S), ("--refresh", args.refresh, MAX_REFRESH_S)):
        if not 0 < value <= most:
            raise InputError(f"{name} {value}: allowed > 0 and <= {most:g} s")
    if not MIN_HEIGHT <= args.height <= MAX_HEIGHT:
        raise InputError(f"--height {args.height}: allowed {MIN_HEIGHT}-{MAX_HEIGHT} rows")
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames {args.frames}: allowed >= 1")
    if args.y_range is not None and not 0 < args.y_range < math.inf:
        raise InputError(f"--range {args.y_range}: allowed a finite number > 0 N m")
    if args.timeout is not None and not 0 <= args.timeout < math.inf:
        raise InputError(f"--timeout {args.timeout}: allowed a finite number of seconds >= 0")
    try:
        sock, sub = wait_for_daemon(args, args.timeout)
        return show(args, sock, sub)
    except KeyboardInterrupt:             # Ctrl-C: the person is done watching
        return 0


def show(args, sock: Path, sub: Subscriber) -> int:
    """Draw (or print, ``--plain``) what ``sub`` receives until ``--frames`` refreshes or Ctrl-C."""
    view = View(args.window, args.height, args.y_range)
    tty = sys.stdout.isatty() and not args.plain
    frames = 0
    with sub:
        if tty:
            sys.stdout.write("\x1b[?25l\x1b[2J")               # hide the cursor, clear
        try:
            next_draw = time.monotonic()
            while args.frames is None or frames < args.frames:
                s = sub.receive(timeout=max(0.0, next_draw - time.monotonic()))
                if s is not None:
                    view.add(s)
                    # drain what is already there before drawing
                    while True:
                        s = sub.receive(timeout=0.0)
                        if s is None:
                            break
                        view.add(s)
                if time.monotonic() < next_draw:
                    continue
                next_draw = time.monotonic() + args.refresh
                frames += 1
                if not tty:
                    print(view.plain(), flush=True)
                    continue
                width = shutil.get_terminal_size((100, 30)).columns
                out = view.status(sock, sub)
                if view.last is not None:
                    for j in range(view.last.joints):
                        out += view.joint_lines(j, width)
                    out.append(view.legend())
                sys.stdout.write("\x1b[H" + "\n".join(line + "\x1b[K" for line in out) + "\x1b[J")
                sys.stdout.flush()
        finally:
            if tty:
                sys.stdout.write("\x1b[?25h\n")
                sys.stdout.flush()
    return 0
