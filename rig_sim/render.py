"""Render images of the marked specimen as seen by the virtual cameras, with exact ground truth.

Scene: a tube (surface of revolution ``r(z)`` about the world z axis) with a smooth tissue-like
texture in a darker bath; black spheres of radius ``marker_radius`` whose centres sit one radius
outside the wall along the outward normal. Each sphere is rendered with its true perspective
outline (a conic in the undistorted image plane, mapped through the lens distortion) by
supersampling small windows, with per-sample occlusion by the tube. Ground truth: the projected
sphere centre and the centroid of the projected (distorted) sphere outline, per camera and marker.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from reconstruction import Camera, project_points

from .refraction import FlatWindow, project_refracted, rays_in_water
from .sensor import SensorModel, expose, illumination_field
from .specimen_geometry import SurfaceOfRevolution

__all__ = ["SceneStyle", "MarkerTruth", "RenderedFrame", "render_markers", "undistort_grid"]

_CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)


@dataclass(frozen=True)
class SceneStyle:
    """Appearance of the scene (relative albedos, texture, spurious blobs).

    Attributes
    ----------
    tissue_albedo, texture_contrast : float
        Mean albedo of the wall and the RMS relative amplitude of its smooth texture.
    bath_albedo : float
        Albedo of everything behind the specimen.
    marker_albedo : float
        Albedo of the black spheres.
    texture_wavelength : float
        Typical wavelength of the wall texture, m.
    n_glare, n_debris : int
        Spurious bright (specular glare) and dark (debris) blobs per image.
    background_step : int
        The background is shaded on a grid every ``background_step`` px and interpolated.
    supersample : int
        Samples per pixel side in the marker windows.
    """

    tissue_albedo: float = 0.62
    texture_contrast: float = 0.08
    bath_albedo: float = 0.12
    marker_albedo: float = 0.03
    texture_wavelength: float = 1.5e-3
    n_glare: int = 3
    n_debris: int = 3
    background_step: int = 4
    supersample: int = 4


@dataclass
class MarkerTruth:
    """Ground truth of one rendered frame.

    Attributes
    ----------
    visible : ndarray, shape (n_cams, n_markers), bool
        The whole sphere is in the image and unoccluded by the specimen.
    coverage : ndarray, shape (n_cams, n_markers)
        Fraction of the projected sphere area left unoccluded (0 for markers not rendered).
    centres : ndarray, shape (n_cams, n_markers, 2)
        Projection of the sphere centre, px (NaN where not visible).
    centroids : ndarray, shape (n_cams, n_markers, 2)
        Area centroid of the projected (distorted) sphere outline, px (NaN where not visible).
    radius_px : ndarray, shape (n_cams, n_markers)
        Mean radius of the projected outline, px (NaN where not visible).
    sphere_centres : ndarray, shape (n_markers, 3)
        Marker sphere centres, m (surface point + radius x normal).
    surface_points : ndarray, shape (n_markers, 3)
        Points on the wall under each marker, m.
    glare, debris : list of ndarray, shape (n_blobs, 2)
        Pixel positions of the spurious blobs per camera.
    """

    visible: np.ndarray
    coverage: np.ndarray
    centres: np.ndarray
    centroids: np.ndarray
    radius_px: np.ndarray
    sphere_centres: np.ndarray
    surface_points: np.ndarray
    glare: list = field(default_factory=list)
    debris: list = field(default_factory=list)


@dataclass
class RenderedFrame:
    """Images of one load step, one per camera, and their ground truth."""

    images: list[np.ndarray]
    truth: MarkerTruth


def undistort_grid(camera: Camera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Distorted pixel coordinates (any matching shapes) -> normalised undistorted coordinates ``(..., 2)``."""
    pts = np.stack([np.asarray(u, float).ravel(), np.asarray(v, float).ravel()], -1).reshape(-1, 1, 2)
    out = cv2.undistortPoints(pts, camera.K, camera.dist, R=None, P=None, criteria=_CRIT)
    return out.reshape(np.shape(u) + (2,))


def _texture(theta: np.ndarray, zeta: np.ndarray, radius: float, wavelength: float, seed: int) -> np.ndarray:
    """Smooth random texture (zero mean, unit RMS), periodic in ``theta`` (rad); ``zeta`` axial, m."""
    rng = np.random.default_rng(seed)
    out = np.zeros(np.shape(theta), np.float32)
    amps = 0.0
    for _ in range(10):
        lam = wavelength * 2.0 ** rng.uniform(-1.2, 1.5)
        ang = rng.uniform(0, np.pi)
        m = np.round(2 * np.pi * radius * np.cos(ang) / lam)  # whole waves around the circumference
        kz = 2 * np.pi * np.sin(ang) / lam
        a = lam**0.7
        out += (a * np.sin(m * theta + kz * zeta + rng.uniform(0, 2 * np.pi))).astype(np.float32)
        amps += a * a / 2
    return out / np.float32(np.sqrt(amps))


def _background(
    camera: Camera, profile: SurfaceOfRevolution, style: SceneStyle, sensor: SensorModel, seed: int, window=None
) -> tuple[np.ndarray, np.ndarray]:
    """Radiance of tube + bath on the full image and the tube coverage on the coarse grid."""
    w, h = camera.image_size
    step = max(1, int(style.background_step))
    nu, nv = -(-w // step), -(-h // step)
    uu = step * np.arange(nu) + (step - 1) / 2
    vv = step * np.arange(nv) + (step - 1) / 2
    U, V = np.meshgrid(uu, vv)
    o_c, d_c = _camera_rays(camera, window, undistort_grid(camera, U, V))
    d = d_c @ camera.R  # world directions (nv, nu, 3)
    C = camera.center if window is None else (o_c - camera.tvec) @ camera.R  # ray origins in the world
    Cx, Cy, Cz = C[..., 0], C[..., 1], C[..., 2]
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (Cx * d[..., 0] + Cy * d[..., 1])
    c0 = Cx**2 + Cy**2
    # closest approach of the ray to the axis: smooth silhouette measure
    t_star = -b / (2 * a)
    z_star = Cz + t_star * d[..., 2]
    rho_min = np.sqrt(np.maximum(c0 - b * b / (4 * a), 0))
    # near intersection with r(z) by fixed-point iteration
    r = np.full_like(a, profile.r.max())
    t = t_star
    for _ in range(5):
        disc = np.maximum(b * b - 4 * a * (c0 - r * r), 0)
        t = (-b - np.sqrt(disc)) / (2 * a)
        r = profile.radius(Cz + t * d[..., 2])
    P = C + t[..., None] * d
    z_hit = P[..., 2]
    dist_len = np.linalg.norm(d, axis=-1)
    m_per_px = t * dist_len / camera.K[0, 0]
    side = (profile.radius(z_star) - rho_min) / (t_star * dist_len / camera.K[0, 0])
    ends = np.minimum(z_hit - profile.z_min, profile.z_max - z_hit) / m_per_px
    cover = np.clip(np.minimum(side, ends) / step + 0.5, 0, 1)
    theta = np.arctan2(P[..., 1], P[..., 0])
    r_mean = float(np.mean(profile.r))
    zeta = (z_hit - profile.z_min) / (profile.z_max - profile.z_min) * 0.035
    tex = _texture(theta, zeta, r_mean, style.texture_wavelength, seed)
    nrm = np.stack([np.cos(theta), np.sin(theta), -profile.slope(z_hit)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    shade = 0.35 + 0.65 * np.clip(-np.sum(nrm * d, -1) / dist_len, 0, 1)
    tissue = style.tissue_albedo * (1 + style.texture_contrast * tex) * shade
    albedo = cover * tissue + (1 - cover) * style.bath_albedo
    illum = illumination_field(U, V, (w, h), sensor, phase=seed % 7)
    coarse = (albedo * illum).astype(np.float32)
    if step > 1:
        full = cv2.resize(coarse, (nu * step, nv * step), interpolation=cv2.INTER_LINEAR)[:h, :w]
    else:
        full = coarse
    return np.ascontiguousarray(full), cover


def _sphere_outline(camera: Camera, centres: np.ndarray, radius: float, n: int = 256) -> np.ndarray:
    """Distorted pixel outline ``(n_markers, n, 2)`` of spheres (world centres ``(n_markers, 3)``)."""
    M = camera.to_camera(centres)
    D = np.linalg.norm(M, axis=-1, keepdims=True)
    e = M / D
    c = M * (1 - radius**2 / D**2)
    a = radius * np.sqrt(D**2 - radius**2) / D
    ref = np.where(np.abs(e[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    u = np.cross(e, ref)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    v = np.cross(e, u)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pts = c[:, None, :] + a[:, None, :] * (np.cos(t)[None, :, None] * u[:, None, :] + np.sin(t)[None, :, None] * v[:, None, :])
    return project_points(camera.K, camera.dist, pts)


def _refracted_outline(camera: Camera, window, centres: np.ndarray, radius: float, n: int = 256) -> np.ndarray:
    """Distorted pixel outline ``(n_markers, n, 2)`` of spheres seen through a flat window.

    Along ``n`` directions from the projected centre in the normalised image plane, bisection finds
    where the refracted ray becomes tangent to the sphere; the points are then distorted exactly.
    """
    M = camera.to_camera(centres)[:, None, :]  # (m, 1, 3)
    q0 = camera.undistort_pixels(project_refracted(camera, window, centres))[:, None, :]  # (m, 1, 2)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    e = np.stack([np.cos(phi), np.sin(phi)], -1)[None]  # (1, n, 2)
    lo = np.zeros((len(centres), n))
    hi = np.broadcast_to(3 * radius / M[..., 2], lo.shape).copy()

    def outside(sv):
        o, d = rays_in_water(camera, window, q0 + sv[..., None] * e)
        m = M - o
        cross = np.cross(m, d)
        return np.linalg.norm(cross, axis=-1) / np.linalg.norm(d, axis=-1) > radius

    for _ in range(48):
        mid = 0.5 * (lo + hi)
        out = outside(mid)
        hi = np.where(out, mid, hi)
        lo = np.where(out, lo, mid)
    q = q0 + (0.5 * (lo + hi))[..., None] * e
    xyz = np.concatenate([q, np.ones(q.shape[:-1] + (1,))], -1)
    return project_points(camera.K, camera.dist, xyz)


def _polygon_centroid(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Area centroids ``(n, 2)`` and areas ``(n,)`` of closed polygons ``(n, m, 2)``."""
    x, y = poly[..., 0], poly[..., 1]
    x1, y1 = np.roll(x, -1, -1), np.roll(y, -1, -1)
    cr = x * y1 - x1 * y
    area = 0.5 * cr.sum(-1)
    cx = ((x + x1) * cr).sum(-1) / (6 * area)
    cy = ((y + y1) * cr).sum(-1) / (6 * area)
    return np.stack([cx, cy], -1), np.abs(area)


def _camera_rays(camera: Camera, window, xy: np.ndarray) -> tuple[np.ndarray | float, np.ndarray]:
    """Rays (camera frame) for normalised undistorted coordinates ``(..., 2)``: origins and directions ``(..., 3)``.

    Without a window the origin is the optical centre (returned as the scalar 0) and the direction ``(x, y, 1)``.
    """
    if window is None:
        return 0.0, np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
    return rays_in_water(camera, window, xy)


def _project(camera: Camera, window, points: np.ndarray) -> np.ndarray:
    return camera.project(points) if window is None else project_refracted(camera, window, points)


def _marker_coverage(
    camera: Camera,
    centres: np.ndarray,
    radius: float,
    profile: SurfaceOfRevolution,
    surf_z: np.ndarray,
    half: int,
    ss: int,
    window=None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Supersampled coverage of sphere markers in square windows.

    Returns
    -------
    origin : ndarray, shape (n, 2), int
        Top-left pixel (u, v) of each window.
    cover : ndarray, shape (n, 2*half+1, 2*half+1)
        Unoccluded sphere coverage per pixel, in [0, 1].
    fraction : ndarray, shape (n,)
        Unoccluded fraction of the sphere's projected area.
    centroid : ndarray, shape (n, 2)
        Centroid of the sphere's whole (occluded or not) image from the samples, px.
    area : ndarray, shape (n,)
        Area of the sphere's whole image from the samples, px^2.
    """
    size = 2 * half + 1
    origin = np.rint(_project(camera, window, centres)).astype(int) - half
    x, y, z, o, fx, fy = _sample_rays(camera, window, origin, size, ss)
    hit, t_s = _sphere_hits(camera, centres, radius, x, y, z, o)
    # the tube can only hide samples that hit a sphere: test those alone (about a third of the window)
    blocked = np.zeros_like(hit)
    where = np.nonzero(hit)
    blocked[where] = _tube_blocks(camera, profile, surf_z, where[0], x[where], y[where],
                                  z if o is None else z[where], None if o is None else o[where], t_s[where])
    seen = hit & ~blocked
    cover = seen.mean(axis=(-1, -2))
    n_hit = hit.sum(axis=(1, 2, 3, 4))
    fraction = np.where(n_hit > 0, seen.sum(axis=(1, 2, 3, 4)) / np.maximum(n_hit, 1), 0.0)
    # sample centroid of the whole sphere image (pixel coords of the samples)
    su = (origin[:, 0, None, None, None, None] + np.arange(size)[None, None, :, None, None] - 0.5 + fx[None, None, None, :, :, 0])
    sv = (origin[:, 1, None, None, None, None] + np.arange(size)[None, :, None, None, None] - 0.5 + fy[None, None, None, :, :, 0])
    w = hit.astype(float)
    cnt = np.maximum(w.sum(axis=(1, 2, 3, 4)), 1)
    centroid = np.stack([(w * su).sum(axis=(1, 2, 3, 4)) / cnt, (w * sv).sum(axis=(1, 2, 3, 4)) / cnt], -1)
    return origin, cover, fraction, centroid, cnt / (ss * ss)


def _blob_stamp(img: np.ndarray, centre: np.ndarray, axes: tuple[float, float], angle: float, value: float, mode: str) -> None:
    """Paint an antialiased ellipse (mode 'mul' darkens to ``value``) or a Gaussian glare ('add')."""
    h, w = img.shape
    half = int(np.ceil(3 * max(axes))) + 2
    u0, v0 = int(round(centre[0])) - half, int(round(centre[1])) - half
    u1, v1 = u0 + 2 * half + 1, v0 + 2 * half + 1
    if u0 < 0 or v0 < 0 or u1 > w or v1 > h:
        return
    V, U = np.mgrid[v0:v1, u0:u1].astype(np.float32)
    c, s = np.cos(angle), np.sin(angle)
    du, dv = U - centre[0], V - centre[1]
    a = (c * du + s * dv) / axes[0]
    b = (-s * du + c * dv) / axes[1]
    rr = np.sqrt(a * a + b * b)
    win = img[v0:v1, u0:u1]
    if mode == "add":
        win += value * np.exp(-0.5 * rr * rr * 4)
    else:
        cov = np.clip((1 - rr) * min(axes) + 0.5, 0, 1)
        win *= 1 - cov * (1 - value)


def render_markers(
    cameras: list[Camera],
    surface_points: np.ndarray,
    normals: np.ndarray,
    profile: SurfaceOfRevolution,
    *,
    marker_radius: float = 0.2e-3,
    style: SceneStyle = SceneStyle(),
    sensor: SensorModel = SensorModel(),
    seed: int = 0,
    windows: list[FlatWindow | None] | None = None,
) -> RenderedFrame:
    """Render one load step in every camera.

    Parameters
    ----------
    cameras : list of Camera
    surface_points : ndarray, shape (n_markers, 3)
        Points on the outer wall under each marker, m (world frame). NaN rows are skipped.
    normals : ndarray, shape (n_markers, 3)
        Outward unit wall normals.
    profile : SurfaceOfRevolution
        The deformed outer wall, used for the background and for occlusion.
    marker_radius : float
        Sphere radius, m (a 0.4 mm marker has 0.2e-3).
    style : SceneStyle
    sensor : SensorModel
    seed : int
        Seeds the noise and spurious blobs (the wall texture is fixed per camera index).
    windows : list of FlatWindow or None, optional
        Per camera, a flat bath window to look through (refraction; ``rig_sim.refraction``). The truth
        centroid is then that of the refracted outline (tangent rays found by bisection).

    Returns
    -------
    RenderedFrame
        ``images`` (uint8 or uint16, shape (H, W) each) and ``truth`` (MarkerTruth).
    """
    pts = np.asarray(surface_points, float)
    nrm = np.asarray(normals, float)
    if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape:
        raise ValueError(f"render_markers: surface_points and normals must both be (n_markers, 3); got {pts.shape}, {nrm.shape}")
    nrm = nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)
    centres = pts + marker_radius * nrm
    n_cam, n_mk = len(cameras), pts.shape[0]
    rng = np.random.default_rng(seed)
    truth = MarkerTruth(
        visible=np.zeros((n_cam, n_mk), bool),
        coverage=np.zeros((n_cam, n_mk)),
        centres=np.full((n_cam, n_mk, 2), np.nan),
        centroids=np.full((n_cam, n_mk, 2), np.nan),
        radius_px=np.full((n_cam, n_mk), np.nan),
        sphere_centres=centres,
        surface_points=pts,
    )
    ss = max(1, int(style.supersample))
    windows = list(windows) if windows is not None else [None] * n_cam
    if len(windows) != n_cam:
        raise ValueError(f"render_markers: windows needs one entry (FlatWindow or None) per camera ({n_cam}); got {len(windows)}")

    def scene(ci: int):  # deterministic (its own seeds), fills only camera ci's truth rows
        radiance, _ = _background(cameras[ci], profile, style, sensor, seed=1000 + ci, window=windows[ci])
        r_px = _stamp_markers(radiance, ci, cameras[ci], windows[ci], centres, pts, nrm, profile, marker_radius,
                              style, sensor, ss, truth)
        return radiance, r_px

    # the cameras' scenes in threads (NumPy and OpenCV release the GIL); the shared random
    # generator (spurious blobs, sensor noise) is then drawn camera by camera, in order
    workers = min(os.cpu_count() or 1, n_cam)
    if workers > 1:
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="render") as pool:
            scenes = list(pool.map(scene, range(n_cam)))
    else:
        scenes = [scene(ci) for ci in range(n_cam)]
    images = []
    for radiance, r_px in scenes:
        _spurious_blobs(radiance, r_px, style, rng, truth)
        images.append(expose(radiance, sensor, rng))
    return RenderedFrame(images, truth)


def _stamp_markers(radiance, ci, cam, win, centres, pts, nrm, profile, marker_radius, style, sensor, ss,
                   truth: MarkerTruth) -> np.ndarray:
    """Paint camera ``ci``'s markers into ``radiance`` (H, W) in place (area coverage, supersampled)
    and fill its rows of ``truth``; returns the markers' image radii (n_markers,) px."""
    w, h = cam.image_size
    view = cam.center - centres
    facing = np.einsum("ij,ij->i", view, nrm) / np.linalg.norm(view, axis=-1)
    p = _project(cam, win, centres)
    depth = cam.to_camera(centres)[:, 2]
    r_px = cam.K[0, 0] * marker_radius / depth * (1.0 if win is None else 1.5 * win.n_water)
    valid = np.isfinite(p).all(-1) & np.isfinite(pts).all(-1) & (facing > -0.3)
    half = int(np.ceil(np.nanmax(np.where(valid, r_px, 0)) * 1.1 + 2)) if valid.any() else 0
    inside = valid & (p[:, 0] - half >= 0) & (p[:, 1] - half >= 0) & (p[:, 0] + half <= w - 1) & (p[:, 1] + half <= h - 1)
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return r_px
    cover_img, frac = _coverage_image(cam, win, centres[idx], pts[idx, 2], marker_radius, profile, half, ss)
    mv, mu = np.nonzero(cover_img)
    cm = cover_img[mv, mu]
    illum = illumination_field(mu.astype(np.float32), mv.astype(np.float32), (w, h), sensor, phase=(1000 + ci) % 7)
    radiance[mv, mu] = radiance[mv, mu] * (1 - cm) + cm * np.float32(style.marker_albedo) * illum
    truth.coverage[ci, idx] = frac
    vi = idx[inside[idx] & (frac >= 0.999)]
    truth.visible[ci, vi] = True
    truth.centres[ci, vi] = p[vi]
    outline = (_sphere_outline(cam, centres[vi], marker_radius) if win is None
               else _refracted_outline(cam, win, centres[vi], marker_radius))
    cen, area = _polygon_centroid(outline)
    truth.centroids[ci, vi] = cen
    truth.radius_px[ci, vi] = np.sqrt(area / np.pi)
    return r_px


def _coverage_image(cam, win, centres, z_ref, marker_radius, profile, half, ss) -> tuple[np.ndarray, np.ndarray]:
    """Marker area coverage of every pixel, (H, W) float32 in 0..1, and each marker's visible
    fraction (n,), in chunks of markers that keep the supersampled patches small."""
    w, h = cam.image_size
    cover = np.zeros(h * w)
    frac = np.zeros(centres.shape[0])
    chunk = max(1, 40000 // ((2 * half + 1) ** 2 * ss * ss // 16 + 1))
    k = np.arange(2 * half + 1)
    for s0 in range(0, centres.shape[0], chunk):
        sel = slice(s0, s0 + chunk)
        origin, cov, frac[sel], _, _ = _marker_coverage(cam, centres[sel], marker_radius, profile, z_ref[sel], half, ss, win)
        uu = origin[:, 0, None, None] + k[None, None, :]
        vv = origin[:, 1, None, None] + k[None, :, None]
        ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h) & (cov > 0)
        cover += np.bincount((vv * w + uu)[ok], weights=cov[ok], minlength=h * w)
    return np.minimum(cover, 1.0).reshape(h, w).astype(np.float32), frac


def _spurious_blobs(radiance, r_px, style: SceneStyle, rng, truth: MarkerTruth) -> None:
    """Glare (bright) and debris (dark, elongated) blobs on the specimen's image region, in place;
    their centres appended to ``truth``."""
    rows, cols = np.nonzero(radiance[::16, ::16] > 0.5 * style.tissue_albedo * 0.5)
    glare, debris = [], []
    if rows.size:
        scale = float(np.nanmedian(r_px)) if np.isfinite(r_px).any() else 5.0
        # (count, major axis / marker radius, minor / major, gain, blend, centres): glare first, as drawn always
        kinds = ((style.n_glare, (0.4, 1.5), (0.4, 1.0), 1.5, "add", glare),
                 (style.n_debris, (0.3, 3.0), (0.15, 0.6), 0.3, "mul", debris))
        for count, size, aspect, gain, blend, centres in kinds:
            for _ in range(count):
                j = rng.integers(rows.size)
                c = np.array([cols[j] * 16 + rng.uniform(0, 16), rows[j] * 16 + rng.uniform(0, 16)])
                ax = scale * rng.uniform(*size)
                _blob_stamp(radiance, c, (ax, ax * rng.uniform(*aspect)), rng.uniform(0, np.pi), gain, blend)
                centres.append(c)
    truth.glare.append(np.array(glare).reshape(-1, 2))
    truth.debris.append(np.array(debris).reshape(-1, 2))


def _sample_rays(camera: Camera, window, origin: np.ndarray, size: int, ss: int):
    """Rays through ss x ss samples of each pixel of n (size, size) windows at ``origin`` (n, 2):
    directions x, y, z (camera frame; z = 1 without a window) and origins o (None without a
    window), each (n, size, size, ss, ss), and the sample offsets fx (1, ss, 1), fy (ss, 1, 1)."""
    # rays at the pixel corners of each window: (n, size+1, size+1, 3)
    k = np.arange(size + 1) - 0.5
    cu = origin[:, 0, None, None] + k[None, None, :]
    cv = origin[:, 1, None, None] + k[None, :, None]
    cu, cv = np.broadcast_arrays(cu, cv)
    g = undistort_grid(camera, cu, cv)
    # bilinear interpolation to ss x ss samples per pixel: (n, size, size, ss, ss, 3)
    f = (np.arange(ss) + 0.5) / ss
    fy = f[:, None, None]
    fx = f[None, :, None]

    weights = ((1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx)

    def interp(g):
        # accumulated in place, in the order of the plain sum g00 w00 + g01 w01 + g10 w10 + g11 w11
        corners = (g[:, :-1, :-1], g[:, :-1, 1:], g[:, 1:, :-1], g[:, 1:, 1:])  # [row, col]
        out = corners[0][:, :, :, None, None] * weights[0]
        tmp = np.empty_like(out)
        for corner, weight in zip(corners[1:], weights[1:]):
            np.multiply(corner[:, :, :, None, None], weight, out=tmp)
            out += tmp
        return out

    if window is None:  # central projection: directions (x, y, 1)
        xy = interp(g)
        return xy[..., 0], xy[..., 1], 1.0, None, fx, fy
    o_c, d_c = rays_in_water(camera, window, g)
    d, o = interp(d_c), interp(o_c)
    return d[..., 0], d[..., 1], d[..., 2], o, fx, fy


def _sphere_hits(camera: Camera, centres, radius, x, y, z, o):
    """Which sample rays hit each marker sphere, and the ray parameter of the first hit."""
    M = camera.to_camera(centres)  # (n, 3)
    Mx, My, Mz = (M[:, i, None, None, None, None] for i in range(3))
    if o is not None:
        Mx, My, Mz = Mx - o[..., 0], My - o[..., 1], Mz - o[..., 2]
    dd = x * x + y * y + z * z
    dm = x * Mx + y * My + z * Mz
    mm = Mx * Mx + My * My + Mz * Mz
    disc_s = dm * dm - dd * (mm - radius * radius)
    return disc_s > 0, (dm - np.sqrt(np.maximum(disc_s, 0))) / dd


def _tube_blocks(camera: Camera, profile: SurfaceOfRevolution, surf_z, marker, x, y, z, o, t_s):
    """Sample rays that meet the tube (a local cone around each marker, world frame) before the
    sphere; ``surf_z`` (n,) the markers' axial positions, m; the other arguments per sample (m,):
    its marker index, ray direction (``z`` scalar without a window), origin ``o`` (m, 3) or None,
    and the ray parameter of the sphere hit."""
    Rt = camera.R
    if o is None:
        Cx, Cy, Cz = camera.center
    else:  # ray origins in the world: R^T (o - t)
        oc = o - camera.tvec
        Cx = Rt[0, 0] * oc[..., 0] + Rt[1, 0] * oc[..., 1] + Rt[2, 0] * oc[..., 2]
        Cy = Rt[0, 1] * oc[..., 0] + Rt[1, 1] * oc[..., 1] + Rt[2, 1] * oc[..., 2]
        Cz = Rt[0, 2] * oc[..., 0] + Rt[1, 2] * oc[..., 1] + Rt[2, 2] * oc[..., 2]
    Dx = Rt[0, 0] * x + Rt[1, 0] * y + Rt[2, 0] * z
    Dy = Rt[0, 1] * x + Rt[1, 1] * y + Rt[2, 1] * z
    Dz = Rt[0, 2] * x + Rt[1, 2] * y + Rt[2, 2] * z
    z0 = surf_z[marker]
    r0 = profile.radius(surf_z)[marker]
    sl = profile.slope(surf_z)[marker]
    q = r0 + sl * (Cz - z0)
    wv = sl * Dz
    A = Dx * Dx + Dy * Dy - wv * wv
    B = 2 * (Cx * Dx + Cy * Dy - q * wv)
    Cc = Cx * Cx + Cy * Cy - q * q
    disc_t = B * B - 4 * A * Cc
    t_t = (-B - np.sqrt(np.maximum(disc_t, 0))) / (2 * A)
    z_t = Cz + t_t * Dz
    return (disc_t > 0) & (t_t > 0) & (t_t < t_s) & (z_t >= profile.z_min) & (z_t <= profile.z_max)
