"""Surface mesh of the marker cloud: specimen axis, cylindrical coordinates, seam-closing Delaunay.

Frames: world frame of the rig (m). The fitted ``Axis`` defines a specimen frame whose z axis is
the fitted axis, oriented towards the load-cell end; cylindrical coordinates (r, theta, z) are taken
in that frame. The mesh is a Delaunay triangulation of the *unrolled* reference surface
(R_mean * theta, z) with markers replicated at theta +/- 2 pi, so that it closes across the angular
seam (above ``STRIP_MARKERS`` markers only those near the seam or the ends are replicated: the same triangles);
triangles are kept once (centroid angle in [-pi, pi)). Sliver triangles are removed and
near-duplicate markers merged away before meshing; the counts are reported in ``SurfaceMesh.dropped``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from ._triangulation import _boundary_edges, _edge_ids, _quality, _remove_vertices, unique_sorted
from .axis import MIN_MARKERS, Axis, to_cylindrical, wrap_angle
from .errors import MeshError
from .step_axes import fit_axis

__all__ = ["Axis", "DUPLICATE_FRACTION", "SLIVER_QUALITY", "SurfaceMesh", "build_mesh", "describe_dropped", "fit_axis",
           "to_cylindrical", "to_trimesh", "wrap_angle"]

log = logging.getLogger(__name__)


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
        What was removed: counts ``nan_markers``, ``duplicate_markers``, ``sliver_markers`` (obtuse
        corners of slivers), ``boundary_slivers``, ``interior_slivers``, the number of interior
        ``holes``; and ``spacing`` (median nearest-neighbour distance, m), ``duplicate_tolerance`` (m),
        ``sliver_quality``. ``describe_dropped`` says it in words.
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


#: Markers closer than this fraction of the median nearest-neighbour distance to another marker are
#: near-duplicates: one of the pair is dropped (measured: docs/validation/identification.md, "Mesh hygiene").
DUPLICATE_FRACTION = 0.35
#: Interior triangles of quality below this lose the marker at their obtuse corner, and the surface is
#: re-meshed (measured: docs/validation/identification.md, "Mesh hygiene").
SLIVER_QUALITY = 0.3
#: Re-meshing rounds at most (each drops the obtuse corners of the slivers left).
MAX_REMESH = 8


def _near_duplicates(points: np.ndarray, tolerance: float, tree: cKDTree | None = None) -> np.ndarray:
    """Which rows of ``points`` (n, 3) lie within ``tolerance`` of an earlier kept row: (n,) bool.

    ``tree``: a ``cKDTree`` of ``points`` if one exists already.
    """
    tree = cKDTree(points) if tree is None else tree
    drop = np.zeros(len(points), bool)
    for i, j in sorted(tree.query_pairs(tolerance)):
        if not drop[i]:
            drop[j] = True
    return drop


#: Above this many markers only a strip of ``SEAM_STRIP`` of the circumference on each side of the seam is
#: replicated (the Delaunay triangles kept are the same; measured in docs/validation/dense.md, "Fourth pass"):
#: Qhull's time is most of a dense cloud's mesh. At or below it every marker is replicated twice, as before.
STRIP_MARKERS = 3000
SEAM_STRIP = 0.25
#: ... and every marker within this fraction of the length of either end (the hull spanning the ends).
END_BAND = 0.1


def _replicate(s: np.ndarray, z: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The unrolled points (s = R theta, z), each shape (n,), replicated at s -/+ 2 pi R: points (m, 2) and
    ``copy`` (3, n), the row of marker i's copy k (k = 0: s - 2 pi R, 1: s, 2: s + 2 pi R) or -1 for none.
    Up to ``STRIP_MARKERS`` markers every marker has its three copies (m = 3 n); above, only the markers within
    ``SEAM_STRIP`` of the circumference of the seam or ``END_BAND`` of the length of an end have shifted copies."""
    n, period = len(s), 2.0 * np.pi * radius
    if n <= STRIP_MARKERS:
        return (np.concatenate([np.column_stack([s + k * period, z]) for k in (-1, 0, 1)]),
                np.arange(3 * n).reshape(3, n))
    width = SEAM_STRIP * period
    # the markers near the two ends are all copied: the convex hull's end chains are then those of every copy
    lo, hi = float(np.min(z)), float(np.max(z))
    end = (z < lo + END_BAND * (hi - lo)) | (z > hi - END_BAND * (hi - lo))
    left = np.flatnonzero(end | (s > 0.5 * period - width))  # copied to s - period, beyond the seam at -pi R
    right = np.flatnonzero(end | (s < width - 0.5 * period))  # copied to s + period
    copy = np.full((3, n), -1)
    copy[1] = np.arange(n)
    copy[0, left] = n + np.arange(len(left))
    copy[2, right] = n + len(left) + np.arange(len(right))
    pts = np.concatenate([np.column_stack([s, z]), np.column_stack([s[left] - period, z[left]]),
                          np.column_stack([s[right] + period, z[right]])])
    return pts, copy


def _owner(copy: np.ndarray, n_points: int) -> np.ndarray:
    """The marker (n_points,) of every replicated point (``_replicate``'s ``copy``)."""
    owner = np.empty(n_points, dtype=np.intp)
    for k in range(3):
        has = copy[k] >= 0
        owner[copy[k][has]] = np.flatnonzero(has)
    return owner


def _delaunay(pts2: np.ndarray) -> np.ndarray:
    """Delaunay simplices (n_tri, 3) of the points ``pts2`` (n, 2); a ``MeshError`` if Qhull fails."""
    try:
        return Delaunay(pts2).simplices
    except Exception as exc:  # scipy raises QhullError on flat/degenerate input
        raise MeshError(f"Delaunay triangulation failed: {exc}") from exc


def _classified(pts2: np.ndarray, simplices: np.ndarray, radius: float):
    """Per triangle of ``simplices`` (t, 3): whether it is kept once (centroid angle in [-pi, pi)), shape (t,)
    bool; its vertices counter-clockwise (t, 3); its quality (-1 for hull triangles spanning the ends), (t,)."""
    s0, s1, s2 = pts2[simplices[:, 0], 0], pts2[simplices[:, 1], 0], pts2[simplices[:, 2], 0]
    centroid_s = (s0 + s1 + s2) / 3.0
    central = (centroid_s >= -np.pi * radius) & (centroid_s < np.pi * radius)
    quality = _quality(pts2, simplices)
    oriented = np.where((quality < 0)[:, None], simplices[:, [0, 2, 1]], simplices)  # make counter-clockwise
    span = (np.maximum(np.maximum(s0, s1), s2) - np.minimum(np.minimum(s0, s1), s2)) / radius
    quality = np.where(span > 0.5 * np.pi, -1.0, np.abs(quality))  # hull triangles spanning the ends
    return central, oriented, quality


def _peel(local: np.ndarray, quality: np.ndarray, min_quality: float) -> tuple[np.ndarray, int]:
    """Peel triangles of quality below ``min_quality`` off the ends, repeatedly: (alive (n_tri,) bool, count).

    A triangle is on the boundary when one of its edges is used by no other living triangle; the
    number of living triangles on each edge is updated as triangles are peeled.
    """
    _, ids, n_edges = _edge_ids(local)
    ids = ids.reshape(3, -1)  # (3, n_tri) edge ids of each triangle
    count = np.bincount(ids.ravel(), minlength=n_edges)
    alive = np.ones(len(local), bool)
    n_peeled = 0
    while True:
        peel = alive & (quality < min_quality) & (count[ids] == 1).any(axis=0)
        if not peel.any():
            return alive, n_peeled
        alive &= ~peel
        count -= np.bincount(ids[:, peel].ravel(), minlength=n_edges)
        n_peeled += int(peel.sum())


def _obtuse_corners(pts2: np.ndarray, simp: np.ndarray) -> np.ndarray:
    """Vertex (into ``pts2``) at the largest angle of each triangle ``simp`` (n_tri, 3): shape (n_tri,)."""
    p = pts2[simp]  # (t, 3, 2)
    opposite = np.roll(p, -1, axis=1) - np.roll(p, 1, axis=1)  # edge opposite each vertex
    longest = np.argmax((opposite**2).sum(-1), axis=1)  # the largest angle faces the longest edge
    return simp[np.arange(len(simp)), longest]


def _clean_triangulation(s, z, radius, min_quality, sliver_quality):
    """Triangulate, dropping the obtuse corner of interior slivers and re-meshing until none is left.

    The re-meshing after dropping markers updates the first triangulation locally
    (``_remove_vertices``: what a full re-triangulation gives, without its cost).

    Returns (kept (n,) bool, local triangles (n_tri, 3) indices into s, quality (n_tri,), alive (n_tri,)
    bool after peeling the ends at ``sliver_quality``, boundary triangles peeled, markers dropped).
    """
    n = len(s)
    kept = np.ones(n, bool)
    n_corner = 0
    pts2, copy = _replicate(s, z, radius)
    owner = _owner(copy, len(pts2))
    simplices = _delaunay(pts2)
    classified = _classified(pts2, simplices, radius)
    for _ in range(MAX_REMESH + 1):
        central, oriented, quality_all = classified
        simp, quality = oriented[central], quality_all[central]
        local = owner[simp]
        alive, n_peeled = _peel(local, quality, max(min_quality, sliver_quality))
        bad = alive & (quality >= 0) & (quality < sliver_quality)  # (hull triangles spanning the ends: < 0)
        if not bad.any() or n_corner >= _MAX_CORNER_FRACTION * n:
            break
        corners = unique_sorted(owner[_obtuse_corners(pts2, simp[bad])])
        kept[corners] = False
        n_corner += len(corners)
        if kept.sum() < MIN_MARKERS:
            raise MeshError(f"meshing needs at least {MIN_MARKERS} markers; only {int(kept.sum())} are left after "
                            "dropping the corners of sliver triangles")
        removed = copy[:, corners].ravel()
        removed = removed[removed >= 0]
        simplices, classified = _without_vertices(pts2, simplices, classified, removed, kept[owner], radius)
    return kept, local, quality, alive, n_peeled, n_corner


def _without_vertices(pts2, simplices, classified, removed, kept, radius):
    """The triangulation ``simplices`` without the vertices ``removed`` (``_remove_vertices``, or a full
    re-triangulation of the ``kept`` points (len(pts2),) bool) and its ``_classified`` arrays: those of the untouched
    triangles carried over (``_remove_vertices`` keeps them first, in order), the new ones' computed."""
    updated = _remove_vertices(pts2, simplices, removed)
    if updated is None:
        sel = np.flatnonzero(kept)
        updated = sel[_delaunay(pts2[sel])]
        return updated, _classified(pts2, updated, radius)
    gone = np.zeros(len(pts2), bool)
    gone[removed] = True
    untouched = ~gone[simplices].any(axis=1)
    n_old = int(untouched.sum())
    fresh = _classified(pts2, updated[n_old:], radius)
    return updated, tuple(np.concatenate([a[untouched], b]) for a, b in zip(classified, fresh))


#: At most this fraction of the markers is dropped as sliver corners (beyond it the cloud is too irregular).
_MAX_CORNER_FRACTION = 0.15


def build_mesh(
    reference: np.ndarray,
    *,
    toward: np.ndarray | None = None,
    min_quality: float = 0.02,
    duplicate_tolerance: float | None = None,
    duplicate_fraction: float = DUPLICATE_FRACTION,
    sliver_quality: float = SLIVER_QUALITY,
) -> SurfaceMesh:
    """Triangulate the reference marker cloud of a tubular specimen.

    Hygiene: near-duplicate markers are dropped, then the surface is meshed; every interior
    triangle of quality below ``sliver_quality`` loses the marker at its obtuse corner and the
    surface is re-meshed (until none is left); thin triangles at the two ends are peeled off.
    Counts in ``SurfaceMesh.dropped`` (:func:`describe_dropped` says them in words).

    Parameters
    ----------
    reference : ndarray, shape (n_markers, 3)
        Reference (stress-free) marker positions in the world frame (m); NaN rows are ignored.
    toward : ndarray, shape (3,), optional
        World direction of the load-cell end (default +z).
    min_quality : float
        Triangles with quality ``4 sqrt(3) A / sum(l^2)`` (1 = equilateral) below this left after the
        clean-up are removed (as small holes).
    duplicate_tolerance : float, optional
        Markers closer than this (m) to an earlier marker are dropped (default ``duplicate_fraction``
        of the median nearest-neighbour distance).
    duplicate_fraction : float
        ``DUPLICATE_FRACTION`` (0.35); 0.05 with ``sliver_quality=0`` is the pre-issue-10 mesh.
    sliver_quality : float
        Quality below which a triangle is a sliver (``SLIVER_QUALITY``, 0.3); 0 keeps every marker
        (only ``min_quality`` applies, the pre-issue-10 behaviour).

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
    idx, spacing, tol = _distinct_markers(ref, np.flatnonzero(finite), duplicate_tolerance, duplicate_fraction)
    n_dup = int(finite.sum()) - len(idx)
    kept, local, quality, alive, n_boundary, n_corner = _clean_triangulation(
        axis.radius * theta[idx], z[idx], axis.radius, min_quality, sliver_quality)
    interior = alive & (quality < min_quality)
    alive &= ~interior
    tri = idx[local[alive]]
    if len(tri) == 0:
        raise MeshError("no usable triangle left after removing slivers")
    bottom_edges, top_edges, n_holes = _end_loops(tri, theta, z, n)
    z_bottom = float(z[bottom_edges].max())
    z_top = float(z[top_edges].min())
    if not z_top > z_bottom:
        raise MeshError(f"the two ends overlap axially (bottom boundary up to z={z_bottom}, top from z={z_top})")
    used = np.zeros(n, bool)
    used[tri.ravel()] = True
    dropped = {"nan_markers": int(n - finite.sum()), "duplicate_markers": n_dup, "sliver_markers": int(n_corner),
               "boundary_slivers": n_boundary, "interior_slivers": int(interior.sum()), "holes": int(n_holes),
               "spacing": spacing, "duplicate_tolerance": tol,
               "duplicate_fraction": tol / spacing if spacing > 0 else float("nan"),
               "sliver_quality": float(sliver_quality)}
    log.info("surface mesh: %d triangles on %d markers; %s", len(tri), int(used.sum()), describe_dropped(dropped))
    return SurfaceMesh(axis=axis, triangles=tri, r=np.where(finite, r, np.nan), theta=np.where(finite, theta, np.nan),
                       z=np.where(finite, z, np.nan), used=used, bottom_edges=bottom_edges, top_edges=top_edges,
                       z_bottom=z_bottom, z_top=z_top, dropped=dropped)


def _distinct_markers(ref: np.ndarray, idx: np.ndarray, tolerance: float | None, fraction: float):
    """The markers ``idx`` (finite rows of ``ref`` (n, 3)) without near-duplicates.

    Returns the kept indices, the median nearest-neighbour distance (m) and the duplicate
    tolerance used (m): ``tolerance``, or ``fraction`` of that spacing.
    """
    tree = cKDTree(ref[idx])
    d_nn, _ = tree.query(ref[idx], k=2)
    spacing = float(np.median(d_nn[:, 1]))
    tol = fraction * spacing if tolerance is None else float(tolerance)
    if np.any(d_nn[:, 1] <= tol):  # (no nearest neighbour within tol: no pair either, skip the pair search)
        idx = idx[~_near_duplicates(ref[idx], tol, tree)]
    if len(idx) < MIN_MARKERS:
        raise MeshError(f"meshing needs at least {MIN_MARKERS} distinct markers; got {len(idx)}")
    return idx, spacing, tol


def _end_loops(tri: np.ndarray, theta: np.ndarray, z: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Bottom and top boundary loops (oriented edges) and the number of interior holes.

    End loops are the components of the boundary-edge graph whose angular winding is +/- 2 pi.
    """
    bnd = _boundary_edges(tri)
    graph = coo_matrix((np.ones(len(bnd)), (bnd[:, 0], bnd[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    comp = labels[bnd[:, 0]]
    dtheta = wrap_angle(theta[bnd[:, 1]] - theta[bnd[:, 0]])
    loops = []
    components = unique_sorted(comp)
    for c in components:
        sel = comp == c
        winding = dtheta[sel].sum() / (2.0 * np.pi)
        if abs(abs(winding) - 1.0) < 0.25:
            loops.append((float(np.mean(z[bnd[sel]])), sel))
    n_holes = len(components) - len(loops)
    if len(loops) != 2:
        raise MeshError(
            f"the markers must cover the whole circumference between two ends; found {len(loops)} "
            "boundary loop(s) that go around the tube (expected 2)"
        )
    loops.sort(key=lambda item: item[0])
    return bnd[loops[0][1]], bnd[loops[1][1]], int(n_holes)


def describe_dropped(dropped: dict) -> str:
    """What the mesh hygiene dropped, in words (from ``SurfaceMesh.dropped``)."""
    parts = []
    if dropped.get("nan_markers"):
        parts.append(f"{dropped['nan_markers']} marker(s) not seen in the reference step")
    if dropped.get("duplicate_markers"):
        parts.append(f"{dropped['duplicate_markers']} near-duplicate marker(s) (closer than "
                     f"{dropped.get('duplicate_tolerance', np.nan) * 1e3:.2g} mm to another, "
                     f"{dropped.get('duplicate_fraction', DUPLICATE_FRACTION):.2g} x the median spacing)")
    if dropped.get("sliver_markers"):
        parts.append(f"{dropped['sliver_markers']} marker(s) at the obtuse corner of sliver triangles "
                     f"(quality < {dropped.get('sliver_quality', SLIVER_QUALITY):g}), then re-meshed")
    if dropped.get("boundary_slivers"):
        parts.append(f"{dropped['boundary_slivers']} thin triangle(s) peeled off the two ends")
    if dropped.get("interior_slivers") or dropped.get("holes"):
        parts.append(f"{dropped.get('interior_slivers', 0)} degenerate triangle(s) left out"
                     + (f" ({dropped['holes']} hole(s) in the mesh)" if dropped.get("holes") else ""))
    return "mesh dropped " + "; ".join(parts) if parts else "mesh dropped nothing"


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
