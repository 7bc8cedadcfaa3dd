"""The rig and the specimen as data: ports, cameras, safety limits, window, simulation (frozen, SI)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from acquisition.protocol._units import MMHG, ConfigError

#: Most cameras a rig file may declare.
MAX_CAMERAS = 64


@dataclass(frozen=True)
class PortConfig:
    """One serial instrument.

    Attributes
    ----------
    port : str
        Device path (``/dev/ttyUSB0``), or ``"sim"`` for the simulated rig.
    serial_number : str
        Expected identity ('' = accept any); checked on connect and on resume.
    mode : str
        ``"controller"`` (the rig sets pressure, Mensor ``Setpt``) or ``"manual"`` (operator).
    baudrate : int
        0 = the driver's default (Mensor 9600, Mark-10 115200).
    measures : str
        Load cell only: ``"wall"`` or ``"total"`` (force on the wall alone, or including the
        pressure end-thrust).
    settings : dict
        Anything else for the driver.
    """

    port: str
    serial_number: str = ""
    mode: str = "manual"
    baudrate: int = 0
    measures: str = "wall"
    settings: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class CameraConfig:
    """One camera: ``backend`` in {'sim', 'folder', 'opencv', 'basler'} and its ``settings``."""

    name: str
    backend: str
    settings: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class SafetyLimits:
    """Pa, L/L0, N."""

    max_pressure: float = 200 * MMHG
    max_stretch: float = 1.6
    max_force: float = 50.0

    def __post_init__(self) -> None:
        # A limit that is NaN or infinite can never trip: refuse it wherever the limits come from.
        for name, floor in (("max_pressure", 0.0), ("max_stretch", 1.0), ("max_force", 0.0)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > floor):
                raise ConfigError(f"safety limit {name} must be a finite number > {floor:g}; got {value!r}")


@dataclass(frozen=True)
class WindowConfig:
    """A flat window between the cameras and the bath (rig file ``[window]`` table); SI.

    The air-side surface of the glass is the plane ``normal . X = plane_distance`` in the world
    frame (the calibration's), ``normal`` (unit) pointing from the cameras into the bath; the glass
    (``glass_thickness``, ``glass_index``) follows, then the bath (``bath_index``).
    """

    glass_thickness: float
    glass_index: float
    bath_index: float
    plane_distance: float
    normal: tuple[float, float, float]
    air_index: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        """The session's record, in the keys of ``reconstruction.refraction.Window.to_dict`` (SI)."""
        return {"normal": list(self.normal), "offset_m": self.plane_distance, "thicknesses_m": [self.glass_thickness],
                "indices": [self.glass_index], "n_bath": self.bath_index, "n_air": self.air_index}


@dataclass(frozen=True)
class SimulationConfig:
    """The simulated specimen behind a ``port = "sim"`` rig (ignored by real rigs).

    ``material`` names one of rig_sim's constitutive laws, used with the seed paper's Table-1
    parameters; ``clamped`` solves the tube with both ends on cannulae (heterogeneous strain)
    instead of the homogeneous membrane.
    """

    material: str = "fung"
    n_markers: int = 300
    clamped: bool = False
    seed: int = 0


SIMULATED_MATERIALS = ("fung", "delfino", "hgo", "neohookean")


@dataclass(frozen=True)
class RigConfig:
    name: str
    pressure: PortConfig
    load_cell: PortConfig
    cameras: tuple[CameraConfig, ...]
    safety: SafetyLimits = field(default_factory=SafetyLimits)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    text: str = field(default="", compare=False, repr=False)
    source: str = field(default="<rig>", compare=False, repr=False)
    #: How this rig holds its specimens: "clamped" (tied on cannulae), "free", or "" (not said).
    ends: str = ""
    #: The flat window the cameras look through into the bath (``[window]``), None = none.
    window: WindowConfig | None = None

    @property
    def simulated(self) -> bool:
        return self.pressure.port == "sim" or self.load_cell.port == "sim"


@dataclass(frozen=True)
class SpecimenFile:
    """Specimen description; lengths in m (file in mm)."""

    specimen_id: str
    radius: float
    length: float
    thickness: float
    notes: str = ""
    #: How this specimen is held: "clamped" (tied on cannulae), "free", or "" (not said).
    ends: str = ""


#: Accepted values of the ``ends`` keys (rig ``[rig]`` table, specimen file).
END_CONDITIONS = ("clamped", "free")
