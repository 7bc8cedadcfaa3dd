"""Acquisition: instruments, cameras, the session file and the operator's session runner.

This is the only stage that talks to hardware; it writes the HDF5 session file that the
other stages read (see ``docs/session-format.md``).
"""

from acquisition.driver_base import Reading
from acquisition.instrument_errors import (DeviceError, Disconnected, GarbledReply, InstrumentError,
                                           InstrumentTimeout)
from acquisition.instruments import open_load_cell, open_pressure
from acquisition.mark10 import Mark10ForceGauge
from acquisition.mensor import MensorPressure
from acquisition.sampler import ChannelRecord, ChannelStatus, Sample, Sampler, SamplerEvent
from acquisition.serial_link import SerialLink, find_port_by_serial
