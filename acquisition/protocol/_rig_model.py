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
class SimFaults:
    """Faults the simulated rig injects (rig file ``[simulation.faults]``), for testing ``vfmlab check-rig``.

    ``defocus``, ``saturate``, ``no_markers``: names of cameras rendered out of focus (Gaussian blur of
    ``defocus_px`` px), over-exposed (gain 4, clipped) or seeing no markers; ``force_drift``: a load cell whose
    zero drifts by this many N/s.
    """

    defocus: tuple[str, ...] = ()
    saturate: tuple[str, ...] = ()
    no_markers: tuple[str, ...] = ()
    force_drift: float = 0.0
    defocus_px: float = 3.0

    @property
    def any(self) -> bool:
        return bool(self.defocus or self.saturate or self.no_markers or self.force_drift)


@dataclass(frozen=True)
class StageConfig:
    """The motorised axial stage (rig file ``[stage]``), SI.

    Attributes
    ----------
    port : str
        Serial port of the Zaber controller, or ``"sim"`` (the simulated stage, ``--sim``).
    microstep_m : float
        Size of one microstep, m.
    min_m, max_m : float
        Soft limits of the carriage position, m.
    x0_m : float
        Carriage position at which the specimen has its gauge length (stretch 1), m.
    direction : {+1, -1}
        +1 when increasing the carriage position lengthens the specimen.
    device, axis : int
        Zaber device address and axis.
    home : bool
        Home the axis before the test (asks the operator first unless ``--yes``).
    timeout_s : float
        Time allowed for one move, s.
    serial_number, baudrate : as for the other instruments.
    """

    port: str
    microstep_m: float
    min_m: float
    max_m: float
    x0_m: float
    direction: int = 1
    device: int = 1
    axis: int = 1
    home: bool = True
    timeout_s: float = 60.0
    serial_number: str = ""
    baudrate: int = 0


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
    faults: SimFaults = field(default_factory=SimFaults)


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
    #: The motorised axial stage (``[stage]``), None = the operator sets the stretch.
    stage: StageConfig | None = None
    #: A cameras calibration file of the rig (``[rig] calibration``), '' = none (check-rig then skips the
    #: markers-in-two-views line).
    calibration: str = ""

    @property
    def simulated(self) -> bool:
        return self.pressure.port == "sim" or self.load_cell.port == "sim" or (
            self.stage is not None and self.stage.port == "sim")


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
