"""What the simulated instruments measure: a first-order pressure plant and the wall force.

Both evaluate lazily at the time given by an injected clock, so tests are deterministic.
"""

from __future__ import annotations

import math
import threading
from typing import Callable

import numpy as np

MechanicsFn = Callable[[float, float], float]


def default_mechanics(pressure_pa: float, stretch: float) -> float:
    """A smooth stand-in for the wall's axial force, N (tension positive).

    ``F = 0.4 N * (stretch - 1) / 0.1 * (1 + 0.5 * p / 13.3 kPa) + 0.02 N * p / 13.3 kPa``: grows with the
    axial stretch and with the pressure (the real artery mechanics from ``rig_sim`` replaces it).
    """
    q = pressure_pa / 13332.2387415
    return 0.4 * (stretch - 1.0) / 0.1 * (1.0 + 0.5 * q) + 0.02 * q


class PressurePlant:
    """Pressure following its target with a first-order response ``dp/dt = (target - p) / tau``.

    Parameters
    ----------
    clock : callable
        Time source (s).
    tau_s : float
        Time constant (s).
    initial_pa : float
        Pressure at the clock's current time (Pa).
    """

    def __init__(self, clock: Callable[[], float], tau_s: float = 0.3, initial_pa: float = 0.0) -> None:
        if tau_s <= 0:
            raise ValueError(f"tau_s must be > 0; got {tau_s}")
        self.clock = clock
        self.tau_s = float(tau_s)
        self._p = float(initial_pa)
        self._target = float(initial_pa)
        self._t = clock()
        self._lock = threading.Lock()

    def _advance(self) -> float:
        t = self.clock()
        dt = max(0.0, t - self._t)
        self._p = self._target + (self._p - self._target) * math.exp(-dt / self.tau_s)
        self._t = t
        return self._p

    def pressure(self) -> float:
        """True pressure now (Pa)."""
        with self._lock:
            return self._advance()

    @property
    def target(self) -> float:
        return self._target

    def set_target(self, target_pa: float) -> None:
        """Move the target from now on (Pa)."""
        with self._lock:
            self._advance()
            self._target = float(target_pa)

    def hold(self) -> None:
        """Keep the present pressure (target := current pressure)."""
        with self._lock:
            self._target = self._advance()


class ForceModel:
    """Load-cell signal: ``mechanics(p, stretch) + offset + drift * t + noise``, in N (tension positive).

    Parameters
    ----------
    plant : PressurePlant
        Where the pressure comes from.
    mechanics : callable, optional
        ``f(pressure_Pa, stretch) -> N`` wall force; default :func:`default_mechanics`.
    offset_n, drift_n_per_s, noise_n : float
        Additive offset, linear drift since creation, Gaussian noise standard deviation.
    end_area_m2 : float
        0 for a cell that reads the wall force; ``pi r_i**2`` (closed cannula of lumen radius ``r_i``) for a
        cell that reads the total force ``F_wall - p * pi r_i**2`` (docs/decisions/0003-load-cell.md).
    rng : numpy.random.Generator
        Noise source.
    """

    def __init__(self, plant: PressurePlant, mechanics: MechanicsFn | None = None, *, offset_n: float = 0.0,
                 drift_n_per_s: float = 0.0, noise_n: float = 0.002, end_area_m2: float = 0.0,
                 rng: np.random.Generator | None = None) -> None:
        if end_area_m2 < 0:
            raise ValueError(f"end_area_m2 must be >= 0; got {end_area_m2}")
        self.end_area_m2 = float(end_area_m2)
        self.plant = plant
        self.mechanics = mechanics or default_mechanics
        self.offset_n = float(offset_n)
        self.drift_n_per_s = float(drift_n_per_s)
        self.noise_n = float(noise_n)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.stretch = 1.0
        self._t0 = plant.clock()

    def true_force(self) -> float:
        """Noise-free force the cell carries now (N): wall force, minus the pressure end-load if any."""
        p = self.plant.pressure()
        return float(self.mechanics(p, self.stretch)) - p * self.end_area_m2

    def signal(self) -> float:
        """What the load cell sees now (N), before any tare."""
        t = self.plant.clock() - self._t0
        noise = self.rng.normal(0.0, self.noise_n) if self.noise_n > 0 else 0.0
        return self.true_force() + self.offset_n + self.drift_n_per_s * t + noise
