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
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from .errors import MeshError

__all__ = ["Axis", "DUPLICATE_FRACTION", "SLIVER_QUALITY", "SurfaceMesh", "build_mesh", "describe_dropped", "fit_axis",
           "to_cylindrical", "to_trimesh", "wrap_angle"]

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
    from .step_axes import fit_clouds  # (step_axes builds on this module)

    centre = pts.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((pts - centre) ** 2, axis=1))))
    best = None
    for d0, c0 in _axis_candidates(pts, centre, initial):
        res, d, o, r = fit_clouds(pts[None], np.ones((1, len(pts))), _frame(d0)[None], np.asarray(c0, float)[None],
                                  scale, profile_degree=int(profile_degree))
        rms = float(np.sqrt(np.mean(res[0] ** 2)))
        if best is None or rms / r[0].mean() < best[0]:
            best = (rms / r[0].mean(), d[0], o[0], r[0], rms)
        if best[0] < 0.05:  # a tube: the most promising principal direction was right
            break
    _, d, o, r, rms = best
    if toward is None:
        toward = np.array([0.0, 0.0, 1.0]) if initial is None else initial.direction
    return _oriented_axis(pts, d, o, r, rms, np.asarray(toward, dtype=float), initial)


def _axis_candidates(pts: np.ndarray, centre: np.ndarray, initial: Axis | None) -> list:
    """Starting (direction, origin) pairs of ``fit_axis``: ``initial``'s, or the three principal
    directions of the cloud, the one with the least relative scatter of the radii about it first."""
    if initial is not None:
        return [(initial.direction, initial.origin)]
    v = pts - centre
    _, _, vt = np.linalg.svd(v, full_matrices=False)

    def spread(d0):  # relative scatter of the radii about the principal direction, before fitting
        r = np.linalg.norm(v - np.outer(v @ d0, d0), axis=1)
        return np.std(r) / np.mean(r)

    return sorted([(d0, centre) for d0 in vt], key=lambda c: spread(c[0]))


def _oriented_axis(pts, d, o, r, rms, toward: np.ndarray, initial: Axis | None) -> Axis:
    """The ``Axis`` of a fitted direction d and origin o: d turned towards ``toward``, the origin moved to
    the markers' mean axial position, the angular origin kept from ``initial`` if given."""
    if d @ toward < 0:
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


def _quality(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """4 sqrt(3) area / sum(edge^2): 1 for equilateral, 0 for degenerate. p (n, 2)."""
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    ab, ac, bc = b - a, c - a, c - b
    area = 0.5 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    s = (ab**2).sum(1) + (ac**2).sum(1) + (bc**2).sum(1)
    return 4.0 * np.sqrt(3.0) * area / np.where(s > 0, s, 1.0)


def _runs(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integer keys (k,) sorted (stable): the order, the sorted keys and which of them starts a run of equal
    keys, (k,) bool. A sort-based ``np.unique`` (numpy >= 2.3 hashes, ~4x slower at these sizes); keys below
    2**31 are sorted as int32 (half the time of int64)."""
    if len(key) and key.max() < 2**31 and key.min() >= 0:
        key = key.astype(np.int32)
    order = np.argsort(key, kind="stable")
    srt = key[order]
    first = np.empty(len(srt), bool)
    first[:1] = True
    np.not_equal(srt[1:], srt[:-1], out=first[1:])
    return order, srt, first


def unique_sorted(a: np.ndarray) -> np.ndarray:
    """``np.unique(a)`` (flattened, sorted) of an integer array, sort-based (see ``_runs``)."""
    srt = np.sort(np.ravel(a))
    return srt[np.concatenate([[True], srt[1:] != srt[:-1]])] if srt.size else srt


def _edge_ids(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Oriented edges of the triangles (3 n_tri, 2), edge (0-1) of every triangle first, then (1-2), (2-0);
    the id of each one's undirected edge (ids in the order of the sorted edge keys), shape (3 n_tri,), and
    the number of distinct edges."""
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    lo, hi = np.minimum(edges[:, 0], edges[:, 1]), np.maximum(edges[:, 0], edges[:, 1])
    key = lo.astype(np.int64) * (int(tri.max(initial=0)) + 1) + hi  # one integer per undirected edge
    order, _, first = _runs(key)
    ids = np.empty(len(key), np.intp)
    ids[order] = np.cumsum(first) - 1
    return edges, ids, int(first.sum())


def _edge_counts(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Oriented edges of the triangles (as ``_edge_ids``) and how many triangles use each one's undirected
    edge, shape (3 n_tri,)."""
    edges, ids, n_edges = _edge_ids(tri)
    return edges, np.bincount(ids, minlength=n_edges)[ids]


def _boundary_edges(tri: np.ndarray) -> np.ndarray:
    """Oriented edges used by exactly one triangle, shape (n, 2)."""
    edges, counts = _edge_counts(tri)
    return edges[counts == 1]


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


def _replicate(s: np.ndarray, z: np.ndarray, radius: float) -> np.ndarray:
    """The unrolled points (s = R theta, z), each shape (n,), replicated at s -/+ 2 pi R: shape (3 n, 2)."""
    period = 2.0 * np.pi * radius
    return np.concatenate([np.column_stack([s + k * period, z]) for k in (-1, 0, 1)])


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


def _orientation(pts2: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Sign of the turn a -> b -> c (indices into ``pts2`` (n, 2)): +1 counter-clockwise, -1 clockwise."""
    pa, pb, pc = pts2[a], pts2[b], pts2[c]
    return np.sign((pb[:, 0] - pa[:, 0]) * (pc[:, 1] - pa[:, 1]) - (pb[:, 1] - pa[:, 1]) * (pc[:, 0] - pa[:, 0]))


def _edges_with_opposite(simp: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edge keys (3 t,), endpoints (3 t, 2) and opposite vertex (3 t,) of triangles ``simp`` (t, 3),
    edge i opposite vertex i (scipy's ``neighbors`` order); n bounds the vertex indices."""
    a = np.concatenate([simp[:, 1], simp[:, 2], simp[:, 0]])
    b = np.concatenate([simp[:, 2], simp[:, 0], simp[:, 1]])
    opposite = np.concatenate([simp[:, 0], simp[:, 1], simp[:, 2]])
    key = np.minimum(a, b).astype(np.int64) * n + np.maximum(a, b)
    return key, np.column_stack([a, b]), opposite


def _cavity_triangles(pts2: np.ndarray, cavity: np.ndarray, verts: np.ndarray) -> np.ndarray | None:
    """The triangles of the Delaunay triangulation of ``verts`` that lie inside the union of ``cavity``.

    The cavity's boundary edges are edges of that triangulation (they are Delaunay edges of the
    remaining points); the triangles on the cavity side of them seed the inside, which spreads to
    neighbours across the other edges. None if Qhull fails or the seeds contradict each other.
    """
    n = len(pts2)
    try:
        dl = Delaunay(pts2[verts])
    except Exception:  # noqa: BLE001 - degenerate cavity: the caller re-triangulates the whole set
        return None
    new = verts[dl.simplices]
    cav_key, cav_ab, cav_opp = _edges_with_opposite(cavity, n)
    order, srt, starts = _runs(cav_key)
    single = starts & np.concatenate([starts[1:], [True]])  # keys seen once: boundary edges of the cavity
    boundary = order[single]  # with the cavity's vertex beyond each
    bkey = cav_key[boundary]  # sorted
    new_key, new_ab, new_opp = _edges_with_opposite(new, n)
    pos = np.searchsorted(bkey, new_key)
    on_boundary = bkey[np.minimum(pos, len(bkey) - 1)] == new_key
    j = boundary[pos[on_boundary]]
    a, b = new_ab[on_boundary, 0], new_ab[on_boundary, 1]
    same_side = _orientation(pts2, a, b, new_opp[on_boundary]) == _orientation(pts2, a, b, cav_opp[j])
    tri_of = np.tile(np.arange(len(new)), 3)[on_boundary]
    # spread the inside from its seeds to neighbouring new triangles across edges that are not cavity edges
    link = ((dl.neighbors.T.ravel() >= 0) & ~on_boundary).reshape(3, -1).T  # (t, 3)
    inside = np.zeros(len(new), bool)
    inside[tri_of[same_side]] = True
    for _ in range(len(new)):
        spread = inside | (inside[dl.neighbors] & link).any(axis=1)
        if np.array_equal(spread, inside):
            break
        inside = spread
    if inside[tri_of[~same_side]].any():  # an outside seed reached: the cavity is not what it should be
        return None
    return new[inside]


def _area(pts2: np.ndarray, simp: np.ndarray) -> float:
    p = pts2[simp]
    return 0.5 * float(np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                              - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])).sum())


def _remove_vertices(pts2: np.ndarray, simplices: np.ndarray, removed: np.ndarray) -> np.ndarray | None:
    """The Delaunay triangulation of ``pts2`` (n, 2) without the vertices ``removed``, updated locally.

    Removing vertices changes a Delaunay triangulation only inside the cavity formed by the triangles
    that use them; the new triangles there are those of the Delaunay triangulation of the cavity's
    remaining vertices that lie in the cavity (in general position the result is the triangulation
    of the reduced point set, as a full re-triangulation gives it; where a removed vertex is on the
    convex hull, the hull shrinks and the new triangles tile the cavity's part inside the new hull).
    Returns None when that cannot be trusted here (the cavity not tiled as it should be): the caller
    then re-triangulates.
    """
    gone = np.zeros(len(pts2), bool)
    gone[removed] = True
    in_cavity = gone[simplices].any(axis=1)
    cavity = simplices[in_cavity]
    touched = np.zeros(len(pts2), bool)
    touched[cavity] = True
    verts = np.flatnonzero(touched & ~gone)  # the cavity's remaining vertices, sorted (as np.unique gives them)
    new = _cavity_triangles(pts2, cavity, verts) if len(verts) >= 3 else None
    if new is None:
        return None
    cavity_area, new_area = _area(pts2, cavity), _area(pts2, new)
    if abs(new_area - cavity_area) > 1e-9 * cavity_area:
        # the convex hull shrinks where a hull vertex goes (then less area is tiled); otherwise not tiled exactly
        # (an edge of a removed vertex used by one triangle only is on the hull: all its triangles are the cavity's)
        edges, counts = _edge_counts(cavity)
        on_hull = np.isin(edges[counts == 1], removed).any()
        if not on_hull or new_area > cavity_area * (1.0 + 1e-9):
            return None
    return np.concatenate([simplices[~in_cavity], new])


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
    pts2 = _replicate(s, z, radius)
    simplices = _delaunay(pts2)
    classified = _classified(pts2, simplices, radius)
    for _ in range(MAX_REMESH + 1):
        central, oriented, quality_all = classified
        simp, quality = oriented[central], quality_all[central]
        local = simp % n
        alive, n_peeled = _peel(local, quality, max(min_quality, sliver_quality))
        bad = alive & (quality >= 0) & (quality < sliver_quality)  # (hull triangles spanning the ends: < 0)
        if not bad.any() or n_corner >= _MAX_CORNER_FRACTION * n:
            break
        corners = unique_sorted(_obtuse_corners(pts2, simp[bad]) % n)
        kept[corners] = False
        n_corner += len(corners)
        if kept.sum() < MIN_MARKERS:
            raise MeshError(f"meshing needs at least {MIN_MARKERS} markers; only {int(kept.sum())} are left after "
                            "dropping the corners of sliver triangles")
        removed = np.concatenate([corners, corners + n, corners + 2 * n])
        simplices, classified = _without_vertices(pts2, simplices, classified, removed, kept, radius)
    return kept, local, quality, alive, n_peeled, n_corner


def _without_vertices(pts2, simplices, classified, removed, kept, radius):
    """The triangulation ``simplices`` without the vertices ``removed`` (``_remove_vertices``, or a full
    re-triangulation of the ``kept`` markers' copies) and its ``_classified`` arrays: those of the untouched
    triangles carried over (``_remove_vertices`` keeps them first, in order), the new ones' computed."""
    updated = _remove_vertices(pts2, simplices, removed)
    if updated is None:
        sel = np.flatnonzero(np.tile(kept, 3))
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
