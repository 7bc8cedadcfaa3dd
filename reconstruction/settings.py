"""The settings of marker reconstruction (:class:`ReconstructionSettings`) and the progress callback's type.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ["Progress", "ReconstructionSettings"]

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class ReconstructionSettings:
    """Tunable settings of the reconstruction (all lengths in m, pixel gates in px).

    Attributes
    ----------
    marker_diameter : float
        Diameter of the spherical markers, m.
    specimen_radius : float or None
        Approximate outer radius of the specimen at the reference step, m (None: bootstrapped
        from markers seen in >= 3 views).
    epipolar_px, max_reprojection_px : float
        Correspondence gates.
    prior_tolerance : float
        Relative radial tolerance of the loose specimen prior (fraction of the radius).
    normals : {"local", "cylinder"}
        Surface normal estimate for the marker-centre offset.
    guided_gate_px : float
        Image-space gate when searching lost markers near their predicted projection.
    min_facing : float
        A camera can see a marker only if the cosine between the outward normal and the direction
        to the camera exceeds this. Slightly negative keeps the views just beyond the limb that
        a ring of few cameras needs for coverage; with >= 6 cameras 0.0 is ~0.1-1 um more
        accurate and ~1 % less complete.
    outlier_factor, outlier_floor : float
        A tracked point farther from its prediction (previous position + neighbours' motion) than
        ``max(outlier_factor * s, outlier_floor)`` (``s`` = median + 1.4826 MAD of all the step's
        prediction residuals; floor in m) is rejected as a bad measurement and reported NaN.
    reference_outlier_factor, reference_outlier_floor : float
        In the reference step, a point farther than ``max(factor * s, floor)`` from the surface
        through its neighbours (:func:`reconstruction.surface.surface_residuals`) is NaN there and
        tracked from its projection on that surface.
    min_view_cos : float
        Views at grazing incidence (cosine between the surface normal and the direction to the
        camera below this) are dropped when at least two better views remain: near the limb the
        marker is seen against the silhouette and its centroid is biased by up to ~0.5 px.
    grazing_bias_px : float
        Centroid bias (px) assumed for such a view when a point cannot do without it (fewer than
        two better views): its uncertainty is computed with this instead of the pixel noise.
    readmit_strong : bool
        Keep a point beyond the outlier limit (below) when it has >= 2 views that all face their
        camera (cosine >= ``min_view_cos``) and a usual reprojection error: near a clamped end the
        neighbours predict the motion poorly, and rejecting it leaves only grazing views to recover it.
    detection : dict
        Extra keyword arguments for :func:`reconstruction.detection.detect_markers`.
    workers : int or None
        Threads detecting the cameras of a step in parallel (None: one per CPU core; 1: serial).
    guided_detection : bool
        From the second loaded step on, search each image only near the tracked markers'
        predicted projections (:func:`detect_step`).
    guided_radius : float
        Search radius around each predicted projection, in expected marker diameters (plus 1.5x
        the 95th percentile of the markers' image motion in the previous step).
    guided_min_fraction : float
        A camera whose guided search finds fewer than this fraction of its previous step's
        detections is searched again over the whole image.
    """

    marker_diameter: float = 0.4e-3
    specimen_radius: float | None = None
    epipolar_px: float = 2.0
    max_reprojection_px: float = 1.5
    prior_tolerance: float = 0.35
    normals: str = "local"
    guided_gate_px: float = 4.0
    min_view_cos: float = 0.35
    grazing_bias_px: float = 0.2
    readmit_strong: bool = True
    min_facing: float = -0.15
    outlier_factor: float = 6.0
    outlier_floor: float = 15e-6
    reference_outlier_factor: float = 5.0
    reference_outlier_floor: float = 30e-6
    sigma_px: float | None = None
    detection: dict = field(default_factory=dict)
    workers: int | None = None
    guided_detection: bool = True
    guided_radius: float = 2.0
    guided_min_fraction: float = 0.98

    def __post_init__(self) -> None:
        if not self.marker_diameter > 0:
            raise ValueError(f"marker_diameter must be > 0 m; got {self.marker_diameter}")
        if self.specimen_radius is not None and not self.specimen_radius > 0:
            raise ValueError(f"specimen_radius must be > 0 m or None; got {self.specimen_radius}")
        if self.normals not in ("local", "cylinder"):
            raise ValueError(f"normals must be 'local' or 'cylinder'; got {self.normals!r}")
