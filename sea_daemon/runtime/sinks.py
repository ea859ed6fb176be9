"""The log writer's other outputs: the estimate as a Lab Streaming Layer stream and as an MCAP recording.

The log writer's process (:mod:`sea_daemon.runtime.logwriter`) drains the loop's rows from its
ring; besides the CSV log it hands every block of rows to these sinks, so that what they carry
is the CSV's values, row for row, and nothing of theirs runs in the real-time loop.  The loop's
row goes on past the CSV's columns with the cycle's start on the loop's clock and the
assistance τ_assist (:data:`sea_daemon.core.log.SINK_LOOP`, :data:`~sea_daemon.core.log.SINK_JOINT`).

* :class:`LslSpec` — an LSL outlet (``pylsl``, ``pip install sea-daemon[lsl]``): one double64
  sample per cycle, channels :func:`channels`, each stamped with the cycle's start on the loop's
  monotonic clock mapped to LSL's (``pylsl.local_clock()``, offset taken when the outlet opens).
* :class:`McapSpec` — ``run-<time>.mcap`` beside the CSV log (``mcap``, ``pip install
  sea-daemon[mcap]``): one JSON message a cycle on ``/sea_daemon/estimate`` with a JSON schema,
  log and publish time the cycle's start mapped to the system's wall clock [ns since the epoch].

docs/interfaces.md §7 describes both.  The specs are what the loop's process gives the writer
(picklable); the writer opens them (:func:`open_sinks`) and reports through a :class:`SinkBoard`
in the shared block: each sink's state and rows delivered, and the first failure's text.  A
sink that fails stops alone: the CSV log goes on.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from sea_daemon.core.log import DaemonLogLayout, column_names
from sea_daemon.errors import InputError

#: the per-joint quantities the sinks carry, in this order: (base name, unit, LSL channel type)
JOINT_CHANNELS = (("tau_h_act_hat", "N*m", "Torque"), ("tau_h_act_bound", "N*m", "TorqueBound"),
                  ("tau_assist", "N*m", "Torque"), ("tau_m", "N*m", "Torque"), ("q", "rad", "Angle"),
                  ("theta_m", "rad", "Angle"))
#: then once per row: (name, unit, LSL channel type)
ROW_CHANNELS = (("valid", "", "Flag"), ("fault", "", "Code"), ("cycle", "", "Count"))
TOPIC = "/sea_daemon/estimate"
SCHEMA = "sea_daemon.Estimate"
EXTRAS = {"lsl": "pylsl", "mcap": "mcap"}

# the board's states of a sink
OPENING, OPEN, CONSUMER, FAILED = 0, 1, 2, -1
MAX_SINKS = 4
LSL_LINGER_S = 2.0          # s an LSL outlet stays open at the end while inlets are connected
MSG_BYTES = 256


def channels(layout: DaemonLogLayout) -> list[tuple[str, int, str, str]]:
    """(label, index in the loop's row, unit, type) of each channel, per-joint quantities first
    (``q`` for one joint, ``q_1 … q_n`` for more, as the CSV names them)."""
    out = []
    for base, unit, kind in JOINT_CHANNELS:
        sl = getattr(layout, base)
        out += [(name, i, unit, kind) for name, i in zip(column_names(base, layout.n), range(sl.start, sl.stop))]
    return out + [(name, getattr(layout, name), unit, kind) for name, unit, kind in ROW_CHANNELS]


def require(output: str) -> None:
    """InputError (exit 2) naming the extra to install when ``output``'s library is missing."""
    try:
        # local import: optional extra, only to see whether it is installed
        __import__(EXTRAS[output])
    except ImportError:
        raise InputError(f"--{output}: the {EXTRAS[output]} package is not installed: "
                         f"pip install sea-daemon[{output}]") from None


@dataclass(frozen=True)
class LslSpec:
    """An LSL outlet named ``name`` for ``n`` joints at ``rate_hz``; the writer waits up to
    ``wait_s`` for a consumer (an inlet) before the loop starts."""

    name: str
    n: int
    rate_hz: float
    wait_s: float = 0.0
    kind = "lsl"

    def open(self, board: "SinkBoard", slot: int) -> "LslSink":
        return LslSink(self, board, slot)

    def describe(self) -> dict:
        return {"output": "lsl", "name": self.name, "source_id": self.source_id}

    @property
    def source_id(self) -> str:
        return f"sea-daemon:{self.name}"


@dataclass(frozen=True)
class McapSpec:
    """An MCAP file at ``path`` for ``n`` joints at ``rate_hz``, beside the CSV log ``log``."""

    path: str
    n: int
    rate_hz: float
    log: str
    kind = "mcap"

    def open(self, board: "SinkBoard", slot: int) -> "McapSink":
        return McapSink(self, board, slot)

    def describe(self) -> dict:
        return {"output": "mcap", "path": self.path}


class SinkBoard:
    """Each sink's state and rows delivered (int64 slots ``2·i``, ``2·i + 1`` of ``slots``) and
    the first failure's text (``msg``, bytes), in the log writer's shared block: written by the
    writer's process, read by the loop's without order (a state seen late is seen next time)."""

    def __init__(self, slots: np.ndarray, msg):
        self.slots, self.msg = slots, msg

    def release(self) -> None:
        """Drop the views of the shared block (before it closes)."""
        if self.msg is not None:
            self.msg.release()
        self.slots = self.msg = None

    def state(self, i: int) -> int:
        return int(self.slots[2 * i])

    def rows(self, i: int) -> int:
        return int(self.slots[2 * i + 1])

    def set(self, i: int, state: int) -> None:
        self.slots[2 * i] = state

    def delivered(self, i: int, rows: int) -> None:
        self.slots[2 * i + 1] += rows

    def fail(self, i: int, what: str) -> None:
        if not any(self.msg[:1]):
            text = what.encode("utf-8", "replace")[:MSG_BYTES - 1]
            self.msg[:len(text)] = text
        self.set(i, FAILED)

    def message(self) -> str:
        return bytes(self.msg).split(b"\0", 1)[0].decode("utf-8", "replace")

    def report(self, specs) -> list[dict]:
        """What each sink did, for the run's summary: its spec's names, ``rows`` delivered,
        ``consumer`` (LSL: an inlet connected) and ``error`` (None when it did not fail)."""
        out = []
        for i, spec in enumerate(specs):
            d = spec.describe()
            d["rows"] = self.rows(i)
            if spec.kind == "lsl":
                d["consumer"] = self.state(i) == CONSUMER
            d["error"] = (self.message() or "failed") if self.state(i) == FAILED else None
            out.append(d)
        return out


def wait_open(board: SinkBoard, count: int, proc, timeout: float) -> list[int]:
    """Wait until each of the ``count`` sinks on ``board`` has left OPENING, or ``timeout`` s
    passed; their states.  InputError with the board's message when one failed, or when the
    writer's process ``proc`` is gone."""
    end = time.monotonic() + timeout
    states: list[int] = []
    while count:
        states = [board.state(i) for i in range(count)]
        if FAILED in states:
            raise InputError(board.message() or "an output failed")
        if OPENING not in states or time.monotonic() > end:
            break
        if not proc.is_alive():
            raise InputError(f"the writer process exited (exit code {proc.exitcode})")
        time.sleep(0.01)
    return states


def _quiet_liblsl(pylsl) -> None:
    """liblsl's INFO lines off (warnings and errors stay) unless the lab has its own
    ``lsl_api.cfg`` (``LSLAPICFG``, ./, ~/lsl_api/, /etc/lsl_api/), which liblsl then reads as is."""
    own = [os.environ.get("LSLAPICFG", ""), "lsl_api.cfg", os.path.expanduser("~/lsl_api/lsl_api.cfg"),
           "/etc/lsl_api/lsl_api.cfg"]
    if any(p and os.path.exists(p) for p in own):
        return
    try:
        pylsl.set_config_content("[log]\nlevel = -1\n")
    except (AttributeError, NotImplementedError):       # an older liblsl: its default logging
        pass


class LslSink:
    """The LSL outlet (see :class:`LslSpec`): double64 channels (:func:`channels`) described in
    ``desc/channels/channel/{label,unit,type}``, nominal rate the loop's."""

    def __init__(self, spec: LslSpec, board: SinkBoard, slot: int):
        # local import: optional extra (pip install sea-daemon[lsl])
        import pylsl
        _quiet_liblsl(pylsl)
        self.board, self.slot = board, slot
        layout = DaemonLogLayout.of(spec.n)
        chans = channels(layout)
        self.index = np.array([c[1] for c in chans])
        self.t_col = layout.cycle_start
        info = pylsl.StreamInfo(spec.name, "Exoskeleton", len(chans), spec.rate_hz, pylsl.cf_double64,
                                spec.source_id)
        desc = info.desc()
        desc.append_child_value("manufacturer", "sea-daemon")
        desc.append_child_value("joints", str(spec.n))
        desc.append_child_value("clock", "the cycle's start on the loop's monotonic clock, mapped to local_clock()")
        xml = desc.append_child("channels")
        for label, _, unit, kind in chans:
            ch = xml.append_child("channel")
            ch.append_child_value("label", label)
            ch.append_child_value("unit", unit)
            ch.append_child_value("type", kind)
        self.outlet = pylsl.StreamOutlet(info)
        # the loop's clock (time.monotonic) to LSL's: one offset, taken now
        self.offset = pylsl.local_clock() - time.monotonic()
        board.set(slot, OPEN)
        if spec.wait_s > 0 and self.outlet.wait_for_consumers(spec.wait_s):
            board.set(slot, CONSUMER)

    def write(self, block: np.ndarray) -> None:
        if self.board.state(self.slot) == OPEN and self.outlet.have_consumers():
            self.board.set(self.slot, CONSUMER)
        stamps = block[:, self.t_col] + self.offset
        self.outlet.push_chunk(np.ascontiguousarray(block[:, self.index]), stamps.tolist())
        self.board.delivered(self.slot, block.shape[0])

    def close(self) -> None:
        """Close the outlet once its inlets went away, or after :data:`LSL_LINGER_S`: samples
        still on their way when an outlet closes are lost to the inlets."""
        end = time.monotonic() + LSL_LINGER_S
        while self.outlet.have_consumers() and time.monotonic() < end:
            time.sleep(0.05)
        self.outlet = None


def _finite(x: float):
    """JSON has no nan or inf: null in their place."""
    return x if math.isfinite(x) else None


class McapSink:
    """The MCAP recording (see :class:`McapSpec`): one JSON message a cycle with the fields of
    :func:`schema`, chunked and zstd-compressed; the file's metadata ``sea_daemon`` names the CSV
    log, the joints, the rate and the clock's mapping."""

    def __init__(self, spec: McapSpec, board: SinkBoard, slot: int):
        # local import: optional extra (pip install sea-daemon[mcap])
        from mcap.writer import Writer
        self.board, self.slot = board, slot
        layout = self.layout = DaemonLogLayout.of(spec.n)
        self.blocks = [(base, getattr(layout, base)) for base, _, _ in JOINT_CHANNELS]
        self.file = open(spec.path, "wb")
        self.writer = Writer(self.file)
        self.writer.start(profile="", library="sea-daemon")
        # the loop's clock (time.monotonic) to the wall clock: one offset, taken now
        self.offset = time.time() - time.monotonic()
        self.writer.add_metadata("sea_daemon", {"log": spec.log, "joints": str(spec.n), "rate_hz": repr(spec.rate_hz),
                                                "monotonic_to_unix_s": repr(self.offset)})
        sid = self.writer.register_schema(SCHEMA, "jsonschema", json.dumps(schema(spec.n)).encode())
        self.channel = self.writer.register_channel(TOPIC, "json", sid)
        self.seq = 0
        board.set(slot, OPEN)

    def write(self, block: np.ndarray) -> None:
        L = self.layout
        for r in block:
            msg = {"t": float(r[L.t]), "cycle": int(r[L.cycle]), "valid": float(r[L.valid]),
                   "fault": int(r[L.fault])}
            for base, sl in self.blocks:
                msg[base] = [_finite(float(x)) for x in r[sl]]
            ns = int(round((float(r[L.cycle_start]) + self.offset) * 1e9))
            self.writer.add_message(self.channel, log_time=ns, data=json.dumps(msg).encode(), publish_time=ns,
                                    sequence=self.seq)
            self.seq += 1
        self.board.delivered(self.slot, block.shape[0])

    def close(self) -> None:
        try:
            self.writer.finish()
            self.file.flush()
            os.fsync(self.file.fileno())
        finally:
            self.file.close()


def schema(n: int) -> dict:
    """The JSON schema of a message on :data:`TOPIC` for ``n`` joints (Foxglove plots its
    numbers: ``/sea_daemon/estimate.tau_h_act_hat[0]``)."""
    num = {"type": "number"}
    joint = {"type": "array", "items": {"type": ["number", "null"]}, "minItems": n, "maxItems": n}
    props = {"t": dict(num, description="the log's t [s]"),
             "cycle": {"type": "integer", "description": "the loop's cycle"},
             "valid": dict(num, description="1: the estimate is valid, 0: not"),
             "fault": {"type": "integer", "description": "the latched fault's code (0: none)"}}
    for base, unit, _ in JOINT_CHANNELS:
        props[base] = dict(joint, description=f"per joint [{unit}] (null: nan or inf in the log)")
    return {"title": SCHEMA, "type": "object", "properties": props, "required": list(props)}


class SinkSet:
    """The writer process's sinks: each opened in turn, each block of rows to each one that has
    not failed; a sink that raises is marked failed on the board and closed, the others go on."""

    def __init__(self, specs, board: SinkBoard):
        self.board, self.sinks = board, []
        for i, spec in enumerate(specs):
            try:
                self.sinks.append(spec.open(board, i))
            except Exception as e:  # noqa: BLE001 - reported on the board, the CSV log goes on
                board.fail(i, f"{spec.kind}: cannot open: {e}")
                self.sinks.append(None)

    def write(self, block: np.ndarray) -> None:
        for i, s in enumerate(self.sinks):
            if s is None:
                continue
            try:
                s.write(block)
            except Exception as e:  # noqa: BLE001 - reported on the board, the CSV log goes on
                self.board.fail(i, f"{type(s).__name__}: {e}")
                self._close(i)

    def _close(self, i: int) -> None:
        s, self.sinks[i] = self.sinks[i], None
        try:
            s.close()
        except Exception as e:  # noqa: BLE001 - reported on the board
            if self.board.state(i) != FAILED:
                self.board.fail(i, f"{type(s).__name__}: cannot close: {e}")

    def close(self) -> None:
        """Close every sink still open, then drop the board's views of the shared block."""
        for i, s in enumerate(self.sinks):
            if s is not None:
                self._close(i)
        self.board.release()
