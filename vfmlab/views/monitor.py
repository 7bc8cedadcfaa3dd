"""``vfmlab monitor``'s views: live readings of the pressure transducer and the load cell as a table or JSON lines."""

from __future__ import annotations

import datetime as _dt
import time

from rich.markup import escape

from vfmlab.display import fixed

__all__ = ["CHANNEL_NAMES", "MMHG_PA", "readings_table", "sample_record"]

MMHG_PA = 133.322387415


def esc(value) -> str:
    """``value`` as text safe inside rich markup."""
    return escape(str(value))

CHANNEL_NAMES = {"pressure": "pressure transducer", "force": "load cell"}


def sample_record(channel: str, sample, device_unit: str | None) -> dict:
    """One sample as a JSON line's fields: SI value and unit, mmHg/kPa for pressure, both clocks, the raw reply."""
    row = {"channel": channel, "seq": sample.seq, "t_monotonic": sample.t_monotonic, "t_wall": sample.t_wall,
           "time": _dt.datetime.fromtimestamp(sample.t_wall, _dt.UTC).isoformat(timespec="milliseconds")}
    if channel == "pressure":
        row.update(value=sample.value, unit="Pa", mmHg=sample.value / MMHG_PA, kPa=sample.value / 1e3)
    else:
        row.update(value=sample.value, unit="N")
    row.update(raw=sample.raw, device_unit=device_unit)
    return row


def readings_table(sampler, devices, started: float):
    """The live table: each instrument's latest reading (mmHg and kPa, or N), state, samples and achieved rate."""
    from rich.table import Table

    table = Table(title="vfmlab monitor  (Ctrl-C to stop)", title_justify="left")
    table.add_column("instrument")
    table.add_column("reading", justify="right")
    table.add_column("", justify="right")
    table.add_column("status")
    table.add_column("samples", justify="right")
    table.add_column("rate", justify="right")
    elapsed = max(time.monotonic() - started, 1e-9)
    for channel in sampler.channels:
        s = sampler.latest(channel)
        st = sampler.status(channel)
        colour = {"ok": "green", "fault": "yellow", "disconnected": "red"}.get(st.state, "white")
        status = f"[{colour}]{esc(st.state)}[/]" + (f" {esc(st.message[:60])}" if st.state != "ok" else "")
        if channel == "pressure":
            name = "pressure"
            reading = "-" if s is None else f"{fixed(s.value / MMHG_PA, 2):>9} mmHg"
            second = "" if s is None else f"{fixed(s.value / 1e3, 3):>8} kPa"
        else:
            name = "force"
            reading = "-" if s is None else f"{fixed(s.value, 4):>9} N"
            second = ""
        table.add_row(name, reading, second, status, str(st.n_ok), f"{st.n_ok / elapsed:6.1f} Hz")
    for channel, dev in devices.items():
        table.caption = (table.caption or "") + f"{channel}: {esc(dev.identity)}  (device unit {esc(dev.unit)})\n"
    return table
