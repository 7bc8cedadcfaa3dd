"""Triangle and edge tools of ``mesh``: quality, edge counts, and the local update of a Delaunay triangulation
when vertices are removed (``_remove_vertices``). Points are 2-D (the unrolled reference surface, m); triangles
are index triples into them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

__all__ = ["unique_sorted"]


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
