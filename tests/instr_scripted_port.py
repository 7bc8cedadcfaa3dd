"""A scripted pyserial port for byte-exact request/reply tests (pymeasure's ``expected_protocol`` idea)."""

from __future__ import annotations

import serial


class ScriptedPort(serial.SerialBase):
    """Checks every write against the next expected request and queues the scripted reply.

    ``script`` is a list of ``(request_bytes, reply_bytes_or_None)``.
    """

    def __init__(self, script: list[tuple[bytes, bytes | None]]) -> None:
        super().__init__()
        self.script = list(script)
        self.rx = bytearray()
        self.is_open = True

    def open(self) -> None:
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self, *args: object) -> None:
        pass

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def read(self, size: int = 1) -> bytes:
        n = min(size, len(self.rx))
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out

    def write(self, data: bytes) -> int:
        if not self.script:
            raise AssertionError(f"unexpected request {bytes(data)!r}: script exhausted")
        expected, reply = self.script.pop(0)
        if bytes(data) != expected:
            raise AssertionError(f"request {bytes(data)!r} != expected {expected!r}")
        if reply:
            self.rx += reply
        return len(data)

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def flush(self) -> None:
        pass

    @property
    def done(self) -> bool:
        return not self.script
