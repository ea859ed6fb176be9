"""The SEA load-side encoder as a CANopen slave: CiA 406 single-turn absolute, 19 bit."""
from __future__ import annotations

from sea_daemon.hw.device_model.slave import SlaveNode


class EncoderNode(SlaveNode):
    """Absolute rotary encoder: 0x6004 = floor(q / 2π · 0x6501) mod (0x6501 · 0x6502)."""

    EDS = "sea_load_encoder.eds"

    def __init__(self, node_id: int, eds=None):
        super().__init__(node_id, eds)
        self.resolution = self._raw(0x6501, 0)
        self.range = self.resolution * max(1, self._raw(0x6502, 0))
        self.position = 0
        self.frozen: int | None = None
        self.jump_counts = 0
        self.add_read_callback(self._on_read)

    def set_resolution(self, counts: int) -> None:
        """Another encoder than the EDS's (the configured joint's): ``counts`` per turn (0x6501)."""
        self.set_data(0x6501, 0, self.object_dictionary[0x6501].encode_raw(int(counts)), check_writable=False)
        self.resolution = int(counts)
        self.range = self.resolution * max(1, self._raw(0x6502, 0))

    def fast_getters(self) -> dict:
        return {0x6004: lambda: self.position}

    def set_counts(self, counts: int) -> None:
        """Sample the encoder: total counts of the joint angle (single-turn part is reported)."""
        if self.frozen is not None:
            self.position = self.frozen
            return
        self.position = (counts + self.jump_counts) % self.range

    def _on_read(self, index: int, subindex: int, od):
        if index == 0x6004:
            return self.position
        return None
