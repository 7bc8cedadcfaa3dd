"""The rich consoles of the CLI (:class:`CliConsole`); imported by ``vfmlab.cli._common`` on first use."""

from __future__ import annotations

from typing import Any, Iterable

from rich.console import Console, ConsoleDimensions

from rich.segment import Segment

from vfmlab.display import LOG_TIME_FORMAT, UNLIMITED_WIDTH, printable


class CliConsole(Console):
    """A rich console that never wraps, crops or pads when its file is not a terminal.

    In a terminal it behaves as :class:`rich.console.Console`. Elsewhere its width is unlimited, long
    text is soft-wrapped (left to the reader), trailing padding is stripped from every line and
    :meth:`rule` prints a short rule instead of one as wide as the console. Everywhere, control
    characters in printed text (an escape sequence in a specimen id) are shown escaped
    (:func:`vfmlab.display.printable`); only rich's own control segments reach the terminal.
    """

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("highlight", False)
        kwargs.setdefault("log_path", False)
        kwargs.setdefault("log_time_format", f"[{LOG_TIME_FORMAT}]")
        self._soft_wrap_terminal = bool(kwargs.pop("soft_wrap", False))
        super().__init__(**kwargs)

    @property
    def size(self) -> ConsoleDimensions:
        dims = super().size
        return dims if self.is_terminal else ConsoleDimensions(UNLIMITED_WIDTH, dims.height)

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        Console.size.fset(self, new_size)

    @property
    def soft_wrap(self) -> bool:  # read by Console.print when soft_wrap is not given
        return self._soft_wrap_terminal or not self.is_terminal

    @soft_wrap.setter
    def soft_wrap(self, value: bool) -> None:
        self._soft_wrap_terminal = bool(value)

    def rule(self, title: str = "", *args: Any, **kwargs: Any) -> None:
        if self.is_terminal:
            super().rule(title, *args, **kwargs)
        else:
            self.print(f"── {title} ──" if title else "──────")

    def _render_buffer(self, buffer: Iterable) -> str:
        buffer = [seg if seg.control else Segment(printable(seg.text), seg.style) for seg in buffer]
        text = super()._render_buffer(buffer)
        if self.is_terminal:
            return text
        return "\n".join(line.rstrip(" ") for line in text.split("\n"))
