"""Fault injection for the device model: what can go wrong on the bus and in the devices.

A fault is written ``KIND[:key=value,...]`` on the command line (``--fault``), e.g.
``drop:target=drive,count=3,at=1.0`` or ``jump:target=encoder,rad=0.5``.

| kind        | effect                                                         | keys (default)          |
|-------------|----------------------------------------------------------------|-------------------------|
| `drop`      | the target's next ``count`` TPDO frames are not sent           | count (1)               |
| `delay`     | the target's next ``count`` TPDO frames leave ``seconds`` late | count (1), seconds (0.05)|
| `stuck`     | the target's encoder count freezes                             |                         |
| `jump`      | the target's encoder count jumps by ``rad`` (joint side)       | rad (0.5)               |
| `emcy`      | the target sends EMCY ``code``; a drive goes to FAULT          | code (0x2310)           |
| `heartbeat` | the target stops its heartbeat                                 |                         |
| `busoff`    | the target's controller goes bus-off (silent and deaf)         |                         |

Common keys: ``target`` (``drive`` | ``encoder``), ``joint`` (0-based, default 0), ``at``
(device time in seconds at which the fault starts; default: now).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from sea_daemon.errors import InputError

KINDS = {
    "drop": {"count": 1},
    "delay": {"count": 1, "seconds": 0.05},
    "stuck": {},
    "jump": {"rad": 0.5},
    "emcy": {"code": 0x2310},
    "heartbeat": {},
    "busoff": {},
}
DEFAULT_TARGET = {"drop": "drive", "delay": "drive", "stuck": "encoder", "jump": "encoder", "emcy": "drive",
                  "heartbeat": "drive", "busoff": "drive"}


@dataclass
class FaultSpec:
    kind: str
    target: str = ""
    joint: int = 0
    at: float | None = None
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"fault kind {self.kind!r}: allowed {', '.join(KINDS)}")
        self.target = self.target or DEFAULT_TARGET[self.kind]
        if self.target not in ("drive", "encoder"):
            raise InputError(f"fault {self.kind}: target {self.target!r}: allowed drive, encoder")
        if self.kind in ("emcy",) and self.target not in ("drive", "encoder"):
            raise InputError(f"fault {self.kind}: target {self.target!r}: allowed drive, encoder")
        unknown = set(self.params) - set(KINDS[self.kind])
        if unknown:
            raise InputError(f"fault {self.kind}: unknown key(s) {', '.join(sorted(unknown))}; "
                             f"allowed: target, joint, at{''.join(', ' + k for k in KINDS[self.kind])}")
        self.params = {**KINDS[self.kind], **self.params}

    def __getitem__(self, key):
        return self.params[key]


def parse_fault(text: str) -> FaultSpec:
    """``KIND[:key=value,...]`` → :class:`FaultSpec` (InputError naming the bad part)."""
    kind, _, rest = text.partition(":")
    kw: dict = {}
    params: dict = {}
    for part in filter(None, rest.split(",")):
        key, eq, value = part.partition("=")
        if not eq:
            raise InputError(f"fault {text!r}: {part!r} is not key=value")
        key = key.strip()
        try:
            num = int(value, 0)
        except ValueError:
            try:
                num = float(value)
            except ValueError:
                num = value.strip()
        if key == "target":
            kw["target"] = str(num)
        elif key == "joint":
            if not isinstance(num, int) or num < 0:
                raise InputError(f"fault {text!r}: joint must be an integer >= 0, got {value!r}")
            kw["joint"] = num
        elif key == "at":
            if not isinstance(num, (int, float)) or num < 0:
                raise InputError(f"fault {text!r}: at must be a time >= 0 s, got {value!r}")
            kw["at"] = float(num)
        else:
            if not isinstance(num, (int, float)) or (num < 0 and key != "rad"):
                raise InputError(f"fault {text!r}: {key} must be a number >= 0, got {value!r}")
            params[key] = num
    return FaultSpec(kind.strip(), params=params, **kw)
