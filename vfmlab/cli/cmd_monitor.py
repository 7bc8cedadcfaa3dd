"""``vfmlab monitor``: live readings of the pressure transducer and the load cell."""

from __future__ import annotations

import json
import time

import click

from vfmlab.cli._common import CliError, console, err_console, esc
from vfmlab.views.monitor import CHANNEL_NAMES as _NAMES

def _open(kind: str, port: str, baud: int, timeout: float):
    from acquisition import InstrumentError, open_load_cell, open_pressure

    opener = open_pressure if kind == "pressure" else open_load_cell
    what = "pressure transducer" if kind == "pressure" else "load cell"
    try:
        return opener(port, baudrate=baud, timeout=timeout)
    except InstrumentError as exc:
        raise CliError(f"cannot open the {what} at {port!r}: {exc}") from exc


EPILOG = """
\b
Examples:
  vfmlab monitor --pressure /dev/ttyUSB0 --load-cell /dev/ttyUSB1
  vfmlab monitor --pressure socket://127.0.0.1:5020 --count 10 --json   # 10 samples as JSON lines
  vfmlab sim-rig          # in another terminal: simulated instruments to try it on
"""


@click.command(epilog=EPILOG)
@click.option("--pressure", "pressure_port", metavar="PORT",
              help="Pressure transducer/controller (Mensor): /dev/ttyUSB0, COM3, socket://HOST:PORT or "
                   "usb-serial:<USB serial number>.")
@click.option("--load-cell", "load_cell_port", metavar="PORT", help="Load cell indicator (Mark-10), same forms.")
@click.option("--rate", default=20.0, show_default=True, type=click.FloatRange(0.1, 1000),
              help="Readings per second of each instrument.")
@click.option("--count", type=click.IntRange(min=1), default=None,
              help="Stop after N samples of each instrument (default: run until Ctrl-C).")
@click.option("--json", "as_json", is_flag=True,
              help="Print every sample as one JSON line (channel, seq, times, value in Pa or N, raw reply).")
@click.option("--zero", is_flag=True, help="Zero (tare) the load cell first. Nothing is ever zeroed or "
                                           "reconfigured without this flag.")
@click.option("--timeout", default=0.25, show_default=True, type=float, help="Seconds allowed for one reply.")
@click.option("--pressure-baud", default=9600, show_default=True, type=int, help="Mensor baud rate.")
@click.option("--load-cell-baud", default=115200, show_default=True, type=int, help="Mark-10 baud rate.")
def command(pressure_port, load_cell_port, rate, count, as_json, zero, timeout, pressure_baud, load_cell_baud):
    """Show live readings of the pressure transducer and the load cell.

    Run this to check the bench before a test: pressure in mmHg and kPa, force in N, the state of each
    instrument and the achieved sample rate. With --count N --json it prints N timestamped samples of each
    instrument as JSON lines, for scripts. Try it without hardware: `vfmlab sim-rig` prints the ports.
    """
    from acquisition import InstrumentError, Sampler

    if not pressure_port and not load_cell_port:
        raise CliError("give at least one instrument: --pressure PORT and/or --load-cell PORT")
    if zero and not load_cell_port:
        raise CliError("--zero tares the load cell; give --load-cell PORT")
    devices = {}
    try:
        if pressure_port:
            devices["pressure"] = _open("pressure", pressure_port, pressure_baud, timeout)
        if load_cell_port:
            devices["force"] = _open("force", load_cell_port, load_cell_baud, timeout)
        if zero:
            try:
                devices["force"].zero()
            except InstrumentError as exc:
                raise CliError(f"zeroing the load cell failed: {exc}") from exc
            err_console.print("load cell zeroed (tared)")
        sampler = Sampler(devices.get("pressure"), devices.get("force"), rate_hz=rate)
        _monitor(sampler, devices, count, as_json, stall_s=max(STALL_S, 5 * timeout))
    finally:
        for dev in devices.values():
            dev.close()


#: With --count: give up when an instrument has delivered nothing new for this long, s.
STALL_S = 5.0


def _monitor(sampler, devices, count, as_json, stall_s: float = STALL_S) -> None:
    from acquisition.sampler import Sample
    from vfmlab.views.monitor import readings_table, sample_record

    printed = {ch: 0 for ch in sampler.channels}
    started = time.monotonic()
    progress = {ch: (0, started) for ch in sampler.channels}  # (samples printed, when that changed)

    def done() -> bool:
        if count is None:
            return False
        now = time.monotonic()
        for ch, n in printed.items():
            if n != progress[ch][0]:
                progress[ch] = (n, now)
            elif n < count and now - progress[ch][1] > stall_s:
                status = sampler.status(ch)
                raise CliError(f"{_NAMES[ch]}: no reading for {now - progress[ch][1]:.0f} s ({status.state}"
                               + (f": {status.message}" if status.message else "") + f"); printed {n} of "
                               f"{count} samples. Check the cable and the port, then try again")
        return all(n >= count for n in printed.values())

    def emit() -> None:
        for channel in sampler.channels:
            rec = sampler.drain(channel)
            for i in range(len(rec)):
                if count is not None and printed[channel] >= count:
                    break
                printed[channel] += 1
                if as_json:
                    s = Sample(int(rec.seq[i]), float(rec.t_monotonic[i]), float(rec.t_wall[i]),
                               float(rec.value[i]), rec.raw[i])
                    click.echo(json.dumps(sample_record(channel, s, devices[channel].unit)))
        for ev in sampler.drain_events():
            err_console.print(f"[yellow]{esc(ev.channel)}: {esc(ev.kind)}[/] {esc(ev.message)}", markup=True)

    try:
        with sampler:
            if as_json:
                while not done():
                    time.sleep(0.02)
                    emit()
            else:
                from rich.live import Live

                with Live(readings_table(sampler, devices, started), console=console, refresh_per_second=8,
                          transient=False) as live:
                    while not done():
                        time.sleep(0.1)
                        emit()
                        live.update(readings_table(sampler, devices, started))
    except KeyboardInterrupt:
        err_console.print("stopped")
