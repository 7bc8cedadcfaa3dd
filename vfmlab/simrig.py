"""``--sim`` wiring: the rig simulator behind the same interfaces as the real rig.

:class:`SimBench` starts ``rig_sim.instruments.SimulatedRig`` (both instruments on real
pseudo-terminals), whose wall force follows the specimen's mechanics, and builds simulated
cameras (:class:`acquisition.cameras.FunctionCamera`) that render the markers on the specimen
deformed at the rig's current pressure and axial stretch. ``acquisition`` never imports
``rig_sim``; this module (the vfmlab layer) connects the two.

The ground truth comes from ``rig_sim.mechanics.simulate_test`` (homogeneous membrane, Fung
law with the paper's parameters) on a (stretch, pressure) grid covering the protocol;
deformations between grid points are interpolated bilinearly. If the mechanics module is not
available an analytic stand-in law is used (logged).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

import numpy as np

from acquisition.cameras import FunctionCamera
from acquisition.errors import InputError
from acquisition.protocol import MMHG, Protocol, RigConfig, SimFaults, SpecimenFile

__all__ = ["SimScene", "SimBench", "serve_until", "simulated_instruments"]

log = logging.getLogger(__name__)


@dataclass
class _Grid:
    stretch: np.ndarray  # (n_l,)
    pressure: np.ndarray  # (n_p,) Pa
    profile_Z: np.ndarray  # (n_z,) m reference
    profile_r: np.ndarray  # (n_l, n_p, n_z) m
    profile_z: np.ndarray  # (n_l, n_p, n_z) m
    force: np.ndarray  # (n_l, n_p) N wall force
    model: str


def _mechanics_grid(spec: SpecimenFile, stretches: np.ndarray, pressures: np.ndarray, n_z: int = 801,
                    material: str = "fung", clamped: bool = False) -> _Grid:
    Zp = np.linspace(-spec.length / 2, spec.length / 2, n_z)
    try:
        from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test
    except ImportError:
        simulate_test = None
    if simulate_test is not None:
        r = np.empty((stretches.size, pressures.size, n_z))
        z = np.empty_like(r)
        f = np.empty((stretches.size, pressures.size))
        for i, lam in enumerate(stretches):
            sim = simulate_test(material, PAPER_PARAMETERS[material], radius=spec.radius, length=spec.length,
                                thickness=spec.thickness, stretches=(float(lam),), pressures=tuple(pressures),
                                # a clamped membrane at L/L0 = 1 goes slack under pressure (singular BVP): there
                                # the homogeneous tube stands in; it is exact for the p = 0 reference and only the
                                # unimaged preconditioning uses it under pressure
                                n_markers=4, clamped=clamped and lam > 1.0 + 1e-9, n_profile=n_z)
            r[i], z[i], f[i] = sim.profile_r[1:], sim.profile_z[1:], sim.axial_force[1:]
        kind = "clamped-end membrane tube" if clamped else "homogeneous membrane"
        return _Grid(stretches, pressures, sim.profile_Z, r, z, f, f"{material} (rig_sim.mechanics, {kind})")
    log.warning("rig_sim.mechanics not available: simulated specimen uses an analytic stand-in law")
    L, P = np.meshgrid(stretches, pressures, indexing="ij")
    lam_t = 1.0 + 0.25 * np.tanh(P / (100 * MMHG)) / np.sqrt(L)  # stiffening inflation
    r = spec.radius * lam_t[..., None] * np.ones(n_z)
    z = L[..., None] * Zp
    area = 2 * np.pi * spec.radius * spec.thickness
    f = area * 60e3 * (L - 1.0) + P * np.pi * (spec.radius * lam_t) ** 2 * 0.5
    return _Grid(stretches, pressures, Zp, r, z, f, "analytic stand-in")


class SimScene:
    """The simulated specimen and camera ring: force and images at any (pressure, stretch).

    Parameters
    ----------
    specimen : SpecimenFile
    protocol : Protocol
        Its stretches and pressures (and preconditioning range) set the grid.
    camera_names : list of str
    image_size : (width, height) px
    n_markers : int
    seed : int
    faults : SimFaults, optional
        Cameras rendered defocused, over-exposed or without markers (``[simulation.faults]``).
    """

    def __init__(self, specimen: SpecimenFile, protocol: Protocol, camera_names: list[str],
                 image_size: tuple[int, int] = (320, 240), n_markers: int = 300, seed: int = 0,
                 material: str = "fung", clamped: bool = False, faults: SimFaults | None = None):
        from rig_sim import camera_ring, random_marker_layout

        pc = protocol.preconditioning
        stretches = {1.0, *(b.stretch for b in protocol.blocks)}
        if pc.stretch_cycles:
            stretches.add(pc.stretch_max)
        p_top = max([max(b.pressures) for b in protocol.blocks] + [pc.pressure_max])
        pressures = np.unique(np.concatenate([np.linspace(0.0, p_top * 1.1 + 1.0, 12),
                                              *[np.asarray(b.pressures) for b in protocol.blocks]]))
        self.grid = _mechanics_grid(specimen, np.array(sorted(stretches)), pressures, material=material,
                                    clamped=clamped)
        self.cameras = camera_ring(len(camera_names), image_size=image_size, seed=seed,
                                   name_format="{}")
        self.camera_names = list(camera_names)
        self.layout = random_marker_layout(n_markers, specimen.radius, specimen.length,
                                           margin=min(4e-3, specimen.length / 5), seed=seed)
        self.image_size = image_size
        self.seed = seed
        self.faults = faults or SimFaults()
        self._lock = threading.Lock()
        self._cache: tuple[float, tuple[float, float], list[np.ndarray]] | None = None
        self.renders = 0
        self.board_view: int | None = None  # calibration board in view (pose index), or None
        self._board_poses: tuple[np.ndarray, np.ndarray] | None = None
        self._board_images: dict[int, list[np.ndarray]] = {}

    # -- mechanics ---------------------------------------------------------------------------
    def _weights(self, pressure: float, stretch: float):
        g = self.grid

        def bracket(x, grid):
            x = float(np.clip(x, grid[0], grid[-1]))
            j = int(np.clip(np.searchsorted(grid, x) - 1, 0, max(grid.size - 2, 0)))
            if grid.size == 1:
                return 0, 0, 0.0
            t = (x - grid[j]) / (grid[j + 1] - grid[j])
            return j, j + 1, t

        return bracket(stretch, g.stretch), bracket(pressure, g.pressure)

    def _interp(self, table: np.ndarray, pressure: float, stretch: float) -> np.ndarray:
        (i0, i1, s), (j0, j1, t) = self._weights(pressure, stretch)
        return ((1 - s) * ((1 - t) * table[i0, j0] + t * table[i0, j1])
                + s * ((1 - t) * table[i1, j0] + t * table[i1, j1]))

    def wall_force(self, pressure: float, stretch: float) -> float:
        """Wall axial force, N, at ``pressure`` Pa and axial stretch L/L0."""
        return float(self._interp(self.grid.force, pressure, stretch))

    def markers(self, pressure: float, stretch: float) -> tuple[np.ndarray, np.ndarray, object]:
        """Marker points on the wall ``(n_markers, 3)`` m, normals and the deformed profile."""
        from rig_sim import SurfaceOfRevolution

        g = self.grid
        r = self._interp(g.profile_r, pressure, stretch)
        z = self._interp(g.profile_z, pressure, stretch)
        Z, th = self.layout.Z, self.layout.theta
        rm, zm = np.interp(Z, g.profile_Z, r), np.interp(Z, g.profile_Z, z)
        dr, dz = np.interp(Z, g.profile_Z, np.gradient(r, g.profile_Z)), np.interp(Z, g.profile_Z, np.gradient(z, g.profile_Z))
        pts = np.stack([rm * np.cos(th), rm * np.sin(th), zm], -1)
        nrm = np.stack([dz * np.cos(th), dz * np.sin(th), -dr], -1)
        nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
        return pts, nrm, SurfaceOfRevolution(z, r)

    # -- rendering ---------------------------------------------------------------------------
    def place_board(self, index: int, n_views: int) -> None:
        """Put the calibration board (``reconstruction.targets.BoardSpec()`` defaults, the
        ``vfmlab calibrate`` defaults) in pose ``index`` of ``n_views`` seeded poses."""
        with self._lock:
            if self._board_poses is None or len(self._board_poses[0]) != n_views:
                from reconstruction import BoardSpec
                from rig_sim.board import board_poses

                self._board_poses = board_poses(self.cameras, BoardSpec(), n_views, seed=self.seed)
                self._board_images = {}
            self.board_view = int(index)

    def remove_board(self) -> None:
        with self._lock:
            self.board_view = None
            self._board_images = {}

    def _board(self, k: int) -> list[np.ndarray]:
        if k not in self._board_images:
            from reconstruction import BoardSpec
            from rig_sim.board import render_board_views

            rv, tv = self._board_poses
            views = render_board_views(self.cameras, BoardSpec(), rv[k:k + 1], tv[k:k + 1], seed=self.seed + k)
            self._board_images[k] = [views.images[c.name][0] for c in self.cameras]
        return self._board_images[k]

    def images(self, pressure: float, stretch: float, max_age_s: float = 0.2) -> list[np.ndarray]:
        """All cameras' images at the state; one render is shared by the cameras of a capture."""
        from rig_sim import render_markers

        with self._lock:
            if self.board_view is not None:
                return self._board(self.board_view)
            now = time.monotonic()
            if self._cache is not None and now - self._cache[0] < max_age_s:
                return self._cache[2]
            pts, nrm, prof = self.markers(pressure, stretch)
            frame = render_markers(self.cameras, pts, nrm, prof, seed=self.seed + self.renders)
            images = self._with_faults(list(frame.images), pts, nrm, prof)
            self.renders += 1
            self._cache = (time.monotonic(), (pressure, stretch), images)
            return images

    def _with_faults(self, images: list[np.ndarray], pts: np.ndarray, nrm: np.ndarray, prof) -> list[np.ndarray]:
        """``images`` with the injected camera faults (``self.faults``) applied."""
        f = self.faults
        if not (f.defocus or f.saturate or f.no_markers):
            return images
        from rig_sim import render_markers
        from rig_sim.camera_faults import defocus, overexpose

        if f.no_markers:
            bare = render_markers(self.cameras, np.full_like(pts[:1], np.nan), nrm[:1], prof,
                                  seed=self.seed + self.renders).images
        for i, name in enumerate(self.camera_names):
            if name in f.no_markers:
                images[i] = bare[i]
            if name in f.defocus:
                images[i] = defocus(images[i], f.defocus_px)
            if name in f.saturate:
                images[i] = overexpose(images[i])
        return images


class SimBench:
    """The simulated rig (instruments on ptys, rendered cameras) for ``vfmlab run --sim``.

    Use as a context manager. Attributes after entering: ``rig`` (SimulatedRig), ``scene``
    (SimScene), ``stretch`` (current L/L0), ``camera_factory`` for ``open_camera``.

    Parameters
    ----------
    time_scale : float
        > 1 makes the simulated pressure plant faster (time constant 0.3 s / time_scale).
    """

    def __init__(self, rig_config: RigConfig, specimen: SpecimenFile, protocol: Protocol, *,
                 time_scale: float = 1.0):
        if rig_config.window is not None:
            # the simulated cameras stand on a ring around the tube: no single flat wall lies between them and the
            # bath, and their images are rendered without one; calibrating through the rig file's window would
            # then bend rays the images never bent
            raise InputError(
                "rig file [window]: the simulated rig (--sim) renders its cameras without a window; expected a rig "
                f"file without a [window] table, got one ({rig_config.window.glass_thickness * 1e3:g} mm glass)")
        self.config, self.specimen, self.protocol = rig_config, specimen, protocol
        self.time_scale = float(time_scale)
        self.simulation = rig_config.simulation
        self._stretch = 1.0
        self.rig = None
        self.scene: SimScene | None = None
        self.stage = None  # rig_sim.zaber_sim.SimulatedStage when the rig file's [stage] port is "sim"

    def __enter__(self) -> SimBench:
        from rig_sim.instruments import SimulatedRig

        cams = [c for c in self.config.cameras if c.backend == "sim"]
        size = (320, 240)
        if cams:
            size = (int(cams[0].settings.get("width", 320)), int(cams[0].settings.get("height", 240)))
        sim = self.simulation
        self.scene = SimScene(self.specimen, self.protocol, [c.name for c in cams], size, sim.n_markers, sim.seed,
                              material=sim.material, clamped=sim.clamped, faults=sim.faults)
        self.rig = SimulatedRig(pressure_source=self.config.pressure.mode,
                                mechanics=self.scene.wall_force, tau_s=0.3 / self.time_scale,
                                rng=np.random.default_rng(self.simulation.seed),
                                force_drift_n_per_s=sim.faults.force_drift)
        if self.config.load_cell.measures == "total":
            # a cell behind a closed cannula reads F_wall - p pi r_i^2 (decision 0003)
            r_i = self.specimen.radius - self.specimen.thickness
            self.rig.force_model.end_area_m2 = float(np.pi * r_i**2)
        self.rig.__enter__()
        if self.config.stage is not None and self.config.stage.port == "sim":
            self._start_stage()
        return self

    def _start_stage(self) -> None:
        """Serve a simulated Zaber axis on a pty; the specimen's stretch then follows its carriage."""
        from rig_sim.zaber_sim import SimulatedStage, ZaberDevice

        sc = self.config.stage
        top = int(np.ceil(sc.max_m / sc.microstep_m)) + 1000
        speed = 20e-3 / sc.microstep_m * self.time_scale  # 20 mm/s, faster with --sim-speed
        device = ZaberDevice(speed=speed, limit_min=0, limit_max=top, start=int(round(sc.x0_m / sc.microstep_m)))
        self.stage = SimulatedStage(device, rng=np.random.default_rng(self.simulation.seed + 7)).start()
        mechanics = self.scene.wall_force
        self.rig.set_mechanics(lambda pressure, _stretch: mechanics(pressure, self.stretch))

    def __exit__(self, *exc: object) -> None:
        if self.stage is not None:
            self.stage.close()
            self.stage = None
        if self.rig is not None:
            self.rig.__exit__(*exc)
            self.rig = None

    @property
    def stretch(self) -> float:
        """The specimen's axial stretch now: the simulated carriage's (with a ``[stage]``), else the last set."""
        if self.stage is None:
            return self._stretch
        from acquisition import stretch_from_position

        sc = self.config.stage
        return stretch_from_position(self.stage.device.position() * sc.microstep_m,
                                     gauge_length_m=self.specimen.length, x0_m=sc.x0_m, direction=sc.direction)

    @property
    def stage_port(self) -> str:
        if self.stage is None:
            raise RuntimeError("the rig file has no [stage] with port = \"sim\"")
        return self.stage.port

    # ports for the drivers
    @property
    def pressure_port(self) -> str:
        return self.rig.pressure_port

    @property
    def load_cell_port(self) -> str:
        return self.rig.load_cell_port

    def set_stretch(self, stretch: float) -> None:
        """The motorised stage of the simulated rig."""
        self.rig.set_stretch(stretch)
        self._stretch = float(stretch)

    def place_board(self, index: int, n_views: int) -> None:
        """The operator's hand placing the calibration board."""
        self.scene.place_board(index, n_views)

    def remove_board(self) -> None:
        self.scene.remove_board()

    def set_operator_pressure(self, pa: float) -> None:
        """The operator's hand on the valve (manual pressure mode)."""
        self.rig.set_operator_pressure(pa)

    def camera_factory(self, name: str, settings: dict) -> FunctionCamera:
        """``open_camera`` factory for backend 'sim'."""
        index = self.scene.camera_names.index(name)

        def render(current: dict) -> np.ndarray:
            return self.scene.images(self.rig.true_pressure(), self.stretch)[index]

        return FunctionCamera(name, render, settings, identity=f"simulated camera {name} (rig_sim ring)")


def simulated_instruments(use_socket: bool, manual: bool, load_cell_measures: str, seed: int):
    """``vfmlab sim-rig``'s instruments (not started): a Mensor CPC controller (``manual``: a CPG2500 indicator)
    and a Mark-10 load cell on pseudo-terminals (``use_socket``: localhost sockets)."""
    from rig_sim.instruments import SimulatedRig

    return SimulatedRig(transport="socket" if use_socket else "pty",
                        pressure_source="manual" if manual else "controller", rng=np.random.default_rng(seed),
                        load_cell_measures=load_cell_measures)


def serve_until(duration: float | None) -> None:
    """Return after ``duration`` s (None: at Ctrl-C or SIGTERM), the simulators serving meanwhile."""
    import signal

    t_end = None if duration is None else time.monotonic() + duration
    previous = None
    if threading.current_thread() is threading.main_thread():
        def handler(signum, frame):
            raise KeyboardInterrupt

        previous = signal.signal(signal.SIGTERM, handler)  # SIGTERM stops the simulators cleanly, as Ctrl-C
    try:
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.05 if t_end is not None else 0.5)
    except KeyboardInterrupt:
        pass
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
