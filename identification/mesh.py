"""Surface mesh of the marker cloud: specimen axis, cylindrical coordinates, seam-closing Delaunay.

Frames: world frame of the rig (m). The fitted ``Axis`` defines a specimen frame whose z axis is
the fitted axis, oriented towards the load-cell end; cylindrical coordinates (r, theta, z) are taken
in that frame. The mesh is a Delaunay triangulation of the *unrolled* reference surface
(R_mean * theta, z) with markers replicated at theta +/- 2 pi, so that it closes across the angular
seam; triangles are kept once (centroid angle in [-pi, pi)). Sliver triangles are removed and
near-duplicate markers merged away before meshing; the counts are reported in ``SurfaceMesh.dropped``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from .errors import MeshError

__all__ = ["Axis", "SurfaceMesh", "fit_axis", "to_cylindrical", "build_mesh", "to_trimesh", "wrap_angle"]

log = logging.getLogger(__name__)

MIN_MARKERS = 12


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles (rad) into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class Axis:
    """A specimen axis in the world frame.

    Attributes
    ----------
    origin : ndarray, shape (3,)
        A point on the axis (m), at the mean axial position of the fitted markers.
    basis : ndarray, shape (3, 3)
        Rows: specimen-frame unit vectors (x', y', z') in world components; z' is the axis,
        pointing to the load-cell end.
    radius : float
        Mean distance of the fitted markers to the axis (m).
    rms : float
        RMS deviation of the marker radii from ``radius`` (m).
    """

    origin: np.ndarray
    basis: np.ndarray
    radius: float
    rms: float

    @property
    def direction(self) -> np.ndarray:
        return self.basis[2]


def _frame(direction: np.ndarray) -> np.ndarray:
    d = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = helper - (helper @ d) * d
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(d, x), d])


def fit_axis(points: np.ndarray, *, toward: np.ndarray | None = None, initial: Axis | None = None,
             profile_degree: int = 4) -> Axis:
    """Fit the axis of a tube (a surface of revolution) to a marker cloud.

    The radius is modelled as a Legendre polynomial of degree ``profile_degree`` in the axial
    coordinate (a bulged or tapered tube keeps its symmetry axis); the axis minimises the
    residual of that profile (variable projection).

    Parameters
    ----------
    points : ndarray, shape (n_markers, 3)
        Marker positions (m); rows with NaN are ignored.
    toward : ndarray, shape (3,), optional
        The axis is oriented to have a positive component along this direction (default world +z,
        or ``initial``'s direction).
    initial : Axis, optional
        Start from this axis (one local fit) instead of trying the three principal directions.
    profile_degree : int
        Degree of the radius profile r(z).

    Returns
    -------
    Axis
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (n_markers, 3); got {pts.shape}")
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < MIN_MARKERS:
        raise MeshError(f"fitting the specimen axis needs at least {MIN_MARKERS} finite markers; got {len(pts)}")
    centre = pts.mean(axis=0)
    deg = int(profile_degree)

    def fit(d0: np.ndarray, c0: np.ndarray):
        frame0 = _frame(d0)

        def geometry(x):
            d = frame0[2] + x[0] * frame0[0] + x[1] * frame0[1]
            d = d / np.linalg.norm(d)
            o = c0 + x[2] * frame0[0] + x[3] * frame0[1]
            v = pts - o
            along = v @ d
            r = np.linalg.norm(v - np.outer(along, d), axis=1)
            return d, o, along, r

        def residual(x):
            _, _, along, r = geometry(x)
            half = max(np.ptp(along) / 2.0, 1e-12)
            basis = np.polynomial.legendre.legvander((along - along.mean()) / half, deg)
            coef = np.linalg.solve(basis.T @ basis, basis.T @ r)
            return r - basis @ coef

        sol = least_squares(residual, np.zeros(4), method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
        d, o, _, r = geometry(sol.x)
        return d, o, r, float(np.sqrt(np.mean(sol.fun**2)))

    if initial is not None:
        candidates = [(initial.direction, initial.origin)]
    else:
        _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
        candidates = [(d0, centre) for d0 in vt]

        def spread(d0):  # relative scatter of the radii about the principal direction, before fitting
            v = pts - centre
            r = np.linalg.norm(v - np.outer(v @ d0, d0), axis=1)
            return np.std(r) / np.mean(r)

        candidates.sort(key=lambda c: spread(c[0]))
    best = None
    for d0, c0 in candidates:
        d, o, r, rms = fit(d0, c0)
        if best is None or rms / r.mean() < best[0]:
            best = (rms / r.mean(), d, o, r, rms)
        if best[0] < 0.05:  # a tube: the most promising principal direction was right
            break
    _, d, o, r, rms = best
    if toward is None:
        toward = np.array([0.0, 0.0, 1.0]) if initial is None else initial.direction
    if d @ np.asarray(toward, dtype=float) < 0:
        d = -d
    o = o + ((pts - o) @ d).mean() * d
    frame = _frame(d)
    if initial is not None:  # keep the angular origin of the initial frame
        x = initial.basis[0] - (initial.basis[0] @ d) * d
        x /= np.linalg.norm(x)
        frame = np.stack([x, np.cross(d, x), d])
    return Axis(origin=o, basis=frame, radius=float(r.mean()), rms=rms)


def to_cylindrical(points: np.ndarray, axis: Axis) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points ``(..., 3)`` -> specimen cylindrical ``(r, theta, z)``, each of shape ``(...)``."""
    local = (np.asarray(points, dtype=float) - axis.origin) @ axis.basis.T
    return np.hypot(local[..., 0], local[..., 1]), np.arctan2(local[..., 1], local[..., 0]), local[..., 2]


@dataclass(frozen=True)
class SurfaceMesh:
    """A triangulated tube surface on the reference markers.

    Attributes
    ----------
    axis : Axis
        Reference specimen axis (z' towards the load-cell end).
    triangles : ndarray, shape (n_triangles, 3) int
        Marker indices (into the original marker array), counter-clockwise in (theta, z), i.e.
        outward normals.
    r, theta, z : ndarray, shape (n_markers,)
        Reference cylindrical coordinates of every marker (NaN where unused).
    used : ndarray, shape (n_markers,) bool
        Markers that are vertices of the mesh.
    bottom_edges, top_edges : ndarray, shape (n_edges, 2) int
        Oriented boundary edges of the two end loops (top = load-cell end).
    z_bottom, z_top : float
        Innermost axial positions of the bottom / top boundary markers (m): every bottom boundary
        marker has z <= z_bottom and every top one z >= z_top.
    dropped : dict
        Counts of what was removed: ``nan_markers``, ``duplicate_markers``, ``boundary_slivers``,
        ``interior_slivers``, and the number of interior ``holes``.
    """

    axis: Axis
    triangles: np.ndarray
    r: np.ndarray
    theta: np.ndarray
    z: np.ndarray
    used: np.ndarray
    bottom_edges: np.ndarray
    top_edges: np.ndarray
    z_bottom: float
    z_top: float
    dropped: dict = field(default_factory=dict)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    @property
    def n_markers(self) -> int:
        return len(self.r)


def _quality(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """4 sqrt(3) area / sum(edge^2): 1 for equilateral, 0 for degenerate. p (n, 2)."""
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    ab, ac, bc = b - a, c - a, c - b
    area = 0.5 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    s = (ab**2).sum(1) + (ac**2).sum(1) + (bc**2).sum(1)
    return 4.0 * np.sqrt(3.0) * area / np.where(s > 0, s, 1.0)


def _boundary_edges(tri: np.ndarray) -> np.ndarray:
    """Oriented edges used by exactly one triangle, shape (n, 2)."""
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return edges[counts[inv.ravel()] == 1]


def _on_boundary(tri: np.ndarray) -> np.ndarray:
    """Which triangles have an edge used by no other triangle, shape (n_triangles,) bool."""
    key = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return (counts[inv.ravel()] == 1).reshape(3, -1).any(axis=0)


def build_mesh(
    reference: np.ndarray,
    *,
    toward: np.ndarray | None = None,
    min_quality: float = 0.02,
    duplicate_tolerance: float | None = None,
) -> SurfaceMesh:
    """Triangulate the reference marker cloud of a tubular specimen.

    Parameters
    ----------
    reference : ndarray, shape (n_markers, 3)
        Reference (stress-free) marker positions in the world frame (m); NaN rows are ignored.
    toward : ndarray, shape (3,), optional
        World direction of the load-cell end (default +z).
    min_quality : float
        Triangles with quality ``4 sqrt(3) A / sum(l^2)`` (1 = equilateral) below this are slivers
        and are removed (peeled from the ends, and removed as small holes inside).
    duplicate_tolerance : float, optional
        Markers closer than this (m) to an earlier marker are dropped (default 5 % of the median
        nearest-neighbour spacing).

    Returns
    -------
    SurfaceMesh
    """
    ref = np.asarray(reference, dtype=float)
    if ref.ndim != 2 or ref.shape[1] != 3:
        raise ValueError(f"reference must have shape (n_markers, 3); got {ref.shape}")
    n = len(ref)
    finite = np.all(np.isfinite(ref), axis=1)
    if finite.sum() < MIN_MARKERS:
        raise MeshError(f"meshing needs at least {MIN_MARKERS} markers in the reference step; got {int(finite.sum())}")
    axis = fit_axis(ref[finite], toward=toward)
    r, theta, z = to_cylindrical(ref, axis)
    idx = np.flatnonzero(finite)

    # Near-duplicate markers (in 3-D): keep the first of each close pair.
    tree = cKDTree(ref[idx])
    d_nn, _ = tree.query(ref[idx], k=2)
    spacing = float(np.median(d_nn[:, 1]))
    tol = 0.05 * spacing if duplicate_tolerance is None else float(duplicate_tolerance)
    drop = np.zeros(len(idx), bool)
    for i, j in sorted(tree.query_pairs(tol)):
        if not drop[i]:
            drop[j] = True
    n_dup = int(drop.sum())
    idx = idx[~drop]
    if len(idx) < MIN_MARKERS:
        raise MeshError(f"meshing needs at least {MIN_MARKERS} distinct markers; got {len(idx)}")

    # Delaunay on the unrolled surface, replicated across the seam.
    s = axis.radius * theta[idx]
    period = 2.0 * np.pi * axis.radius
    pts2 = np.concatenate([np.column_stack([s + k * period, z[idx]]) for k in (-1, 0, 1)])
    try:
        dl = Delaunay(pts2)
    except Exception as exc:  # scipy raises QhullError on flat/degenerate input
        raise MeshError(f"Delaunay triangulation failed: {exc}") from exc
    simp = dl.simplices
    centroid_s = pts2[simp, 0].mean(axis=1)
    keep = (centroid_s >= -np.pi * axis.radius) & (centroid_s < np.pi * axis.radius)
    simp = simp[keep]
    quality = _quality(pts2, simp)
    simp = np.where((quality < 0)[:, None], simp[:, [0, 2, 1]], simp)  # make counter-clockwise
    quality = np.abs(quality)
    span = np.ptp(pts2[simp, 0], axis=1) / axis.radius
    quality = np.where(span > 0.5 * np.pi, -1.0, quality)  # hull triangles spanning the ends
    local = simp % len(idx)

    # Remove slivers: peel bad triangles off the ends, then drop interior ones (small holes).
    alive = np.ones(len(local), bool)
    n_boundary = 0
    while True:
        on_bnd = np.zeros(len(local), bool)
        on_bnd[alive] = _on_boundary(local[alive])
        peel = alive & on_bnd & ((quality < min_quality) | (quality < 0))
        if not peel.any():
            break
        alive &= ~peel
        n_boundary += int(peel.sum())
    interior = alive & ((quality < min_quality) | (quality < 0))
    alive &= ~interior
    tri = idx[local[alive]]
    if len(tri) == 0:
        raise MeshError("no usable triangle left after removing slivers")

    # End loops: components of the boundary-edge graph whose angular winding is +/- 2 pi.
    bnd = _boundary_edges(tri)
    graph = coo_matrix((np.ones(len(bnd)), (bnd[:, 0], bnd[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    comp = labels[bnd[:, 0]]
    dtheta = wrap_angle(theta[bnd[:, 1]] - theta[bnd[:, 0]])
    loops = []
    for c in np.unique(comp):
        sel = comp == c
        winding = dtheta[sel].sum() / (2.0 * np.pi)
        if abs(abs(winding) - 1.0) < 0.25:
            loops.append((float(np.mean(z[bnd[sel]])), sel))
    n_holes = len(np.unique(comp)) - len(loops)
    if len(loops) != 2:
        raise MeshError(
            f"the markers must cover the whole circumference between two ends; found {len(loops)} "
            "boundary loop(s) that go around the tube (expected 2)"
        )
    loops.sort(key=lambda item: item[0])
    bottom_edges, top_edges = bnd[loops[0][1]], bnd[loops[1][1]]
    z_bottom = float(z[np.unique(bottom_edges)].max())
    z_top = float(z[np.unique(top_edges)].min())
    if not z_top > z_bottom:
        raise MeshError(f"the two ends overlap axially (bottom boundary up to z={z_bottom}, top from z={z_top})")
    used = np.zeros(n, bool)
    used[tri.ravel()] = True
    dropped = {
        "nan_markers": int(n - finite.sum()),
        "duplicate_markers": n_dup,
        "boundary_slivers": n_boundary,
        "interior_slivers": int(interior.sum()),
        "holes": int(n_holes),
    }
    words = {"nan_markers": "markers without a position", "duplicate_markers": "duplicate markers",
             "boundary_slivers": "sliver triangles at the ends", "interior_slivers": "sliver triangles inside",
             "holes": "holes"}
    left_out = ", ".join(f"{v} {words[k]}" for k, v in dropped.items() if v) or "nothing"
    if n_dup or interior.any() or n_holes:
        log.warning("surface mesh: %d triangles on %d markers; left out %s", len(tri), int(used.sum()), left_out)
    else:
        log.info("surface mesh: %d triangles on %d markers; left out %s", len(tri), int(used.sum()), left_out)
    return SurfaceMesh(axis=axis, triangles=tri, r=np.where(finite, r, np.nan), theta=np.where(finite, theta, np.nan),
                       z=np.where(finite, z, np.nan), used=used, bottom_edges=bottom_edges, top_edges=top_edges,
                       z_bottom=z_bottom, z_top=z_top, dropped=dropped)


def to_trimesh(mesh: SurfaceMesh, positions: np.ndarray | None = None):
    """A ``trimesh.Trimesh`` of the mesh at given positions (default reference), world frame, m.

    Parameters
    ----------
    positions : ndarray, shape (n_markers, 3), optional
        Marker positions of one step; default: the reference positions rebuilt from the mesh.
    """
    import trimesh

    if positions is None:
        local = np.column_stack([mesh.r * np.cos(mesh.theta), mesh.r * np.sin(mesh.theta), mesh.z])
        positions = local @ mesh.axis.basis + mesh.axis.origin
    return trimesh.Trimesh(vertices=np.nan_to_num(np.asarray(positions, float)), faces=mesh.triangles, process=False)
