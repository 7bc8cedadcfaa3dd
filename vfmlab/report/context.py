"""What the report's sections read: the open session, its latest results, the surface fields and the global curves,
each computed once."""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from acquisition.session import DamagedSessionError, Session
from vfmlab.fields import FieldsError, SurfaceFields, compute_fields, stress_strain_curves
from vfmlab.report import curves
from vfmlab.report.page import absent

log = logging.getLogger(__name__)

__all__ = ["Context"]


class Context:
    """The open session, its results (damaged ones left out and listed in ``damaged``) and the computed fields."""

    def __init__(self, session: Session):
        self.session = session
        self.steps = session.steps
        self.damaged: list[str] = []
        self.markers = self._read(lambda: session.latest("markers"))
        self.calibration = self._read(lambda: session.latest("calibration"))
        self.idents = [r for r in (self._read(functools.partial(session.result, n))
                                   for n in session.results("identification")) if r is not None]
        latest: dict[tuple[str, str], Mapping[str, Any]] = {}
        for r in self.idents:  # newest result per (model, wall)
            latest[(str(r["attrs"].get("model", "?")), str(r["attrs"].get("wall", "")))] = r
        self.latest_idents = list(latest.values())
        self.fields: SurfaceFields | None = None
        self.fields_error: str | None = None
        self._curves: dict[str, Any] | None = None
        self._fits: dict[str, Any] | None = None
        self._reachable: dict[str, Any] = {}
        if self.markers is not None:
            try:
                self.fields = compute_fields(self.markers, self.steps, self.latest_idents)
            except (FieldsError, ValueError, np.linalg.LinAlgError) as exc:
                self.fields_error = str(exc)
                log.warning("surface fields unavailable: %s", exc)

    def _read(self, read: Callable[[], Any]) -> Any:
        """A result, or None (and the reason logged and kept in ``damaged``) when it is damaged."""
        try:
            return read()
        except DamagedSessionError as exc:
            log.warning("%s", exc)
            self.damaged.append(str(exc))
            return None

    def no_fields(self) -> str:
        if self.markers is None:
            return absent("No marker reconstruction is stored in this session (run 'vfmlab reconstruct' or "
                          "'vfmlab import-markers'), so there are no surface fields to show.")
        return absent(f"The surface fields could not be computed from {self.markers['name']}: {self.fields_error}")

    def reachable(self, result: Mapping[str, Any]) -> Any:
        """The half-widths the bound allows this identification result
        (:func:`vfmlab.stages.reachable.session_reachable`; never raises), computed once per result."""
        if result["name"] not in self._reachable:
            from vfmlab.stages.reachable import session_reachable

            self._reachable[result["name"]] = session_reachable(self.session, result)
        return self._reachable[result["name"]]

    def curves(self) -> dict[str, Any]:
        """The mean mid-span curves (:func:`vfmlab.fields.stress_strain_curves`); needs ``fields``."""
        if self._curves is None:
            if self.fields is None:
                raise ValueError("the mid-span curves need the surface fields; check fits() is not None first")
            self._curves = stress_strain_curves(self.fields, self.fields.force, self.session.specimen.thickness,
                                                self.session.load_cell_measures, self.latest_idents)
        return self._curves

    def fits(self) -> dict[str, Any] | None:
        """Measured and model pressure/force along the measured path (:func:`curves.fit_curves`), or None without
        surface fields."""
        if self.fields is None:
            return None
        if self._fits is None:
            self._fits = curves.fit_curves(self.curves(), self.fields.pressure, self.fields.force)
        return self._fits
