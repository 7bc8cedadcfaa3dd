"""Synthetic data for the reconstruction tests: a camera ring, a marked deforming cylinder,
and simple rendered images of dark discs (antialiased by supersampling)."""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.cameras import Camera


def camera_ring(n=6, distance=0.12, f=6000.0, size=(2448, 2048), height=0.0, dist=(-0.08, 0.15, 4e-4, -3e-4, 0.0)):
    """n cameras on a circle of ``distance`` m around the z axis, looking at the origin."""
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.1
        C = np.array([distance * np.cos(a), distance * np.sin(a), height])
        zc = -C / np.linalg.norm(C)
        xc = np.cross([0, 0, 1.0], zc)
        xc /= np.linalg.norm(xc)
        yc = np.cross(zc, xc)
        R = np.stack([xc, yc, zc])
        rvec = cv2.Rodrigues(R)[0].ravel()
        K = np.array([[f, 0, size[0] / 2 - 0.5 + 3 * i], [0, f * 1.0005, size[1] / 2 - 0.5 - 2 * i], [0, 0, 1]])
        cams.append(Camera(f"cam{i}", K, dist, rvec, -R @ C, size))
    return cams


def cylinder_markers(n=300, radius=4e-3, length=16e-3, seed=0, min_sep=0.9e-3):
    """Marker *surface* points spread over a cylinder (Poisson-disc-like), shape (n, 3)."""
    rng = np.random.default_rng(seed)
    pts = []
    while len(pts) < n:
        th = rng.uniform(0, 2 * np.pi)
        z = rng.uniform(-length / 2, length / 2)
        p = np.array([radius * np.cos(th), radius * np.sin(th), z])
        if all(np.linalg.norm(p - q) > min_sep for q in pts):
            pts.append(p)
    return np.array(pts)


def deform(points, radial_stretch=1.0, axial_stretch=1.0, twist=0.0, bulge=0.0, length=16e-3):
    """Axisymmetric map: r -> r * radial_stretch * (1 + bulge cos(pi z / L)), z -> z * axial, theta += twist z / L."""
    r = np.hypot(points[:, 0], points[:, 1])
    th = np.arctan2(points[:, 1], points[:, 0])
    z = points[:, 2]
    r2 = r * radial_stretch * (1 + bulge * np.cos(np.pi * z / length))
    th2 = th + twist * z / length
    return np.stack([r2 * np.cos(th2), r2 * np.sin(th2), z * axial_stretch], 1)


def visible_in(cams, surface, normals, min_cos=0.25):
    """(n_cams, n) bool: the outward normal faces the camera (self-occlusion of a convex tube) and in image."""
    out = []
    for c in cams:
        v = c.center - surface
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        px = c.project(surface)
        inside = (px[:, 0] > 20) & (px[:, 1] > 20) & (px[:, 0] < c.image_size[0] - 20) & (px[:, 1] < c.image_size[1] - 20)
        out.append((np.sum(v * normals, 1) > min_cos) & inside)
    return np.array(out)


def render_discs(size, centres, diameters, *, background=180.0, black=25.0, blur=0.8, noise=1.5, gradient=0.3,
                 texture=0.0, seed=0, supersample=8, dtype=np.uint8):
    """Dark antialiased discs on a lit background. ``size`` = (W, H)."""
    rng = np.random.default_rng(seed)
    W, H = size
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    light = background * (1 + gradient * (xx / W - 0.5) + 0.5 * gradient * (yy / H - 0.5))
    if texture > 0:
        t = rng.normal(size=(H // 8 + 2, W // 8 + 2)).astype(np.float32)
        t = cv2.resize(t, (W, H), interpolation=cv2.INTER_CUBIC)
        light = light * (1 + texture * t)
    cover = np.zeros((H, W), np.float32)
    s = supersample
    sub = (np.arange(s) + 0.5) / s - 0.5
    for (cx, cy), d in zip(np.asarray(centres, float), np.broadcast_to(diameters, (len(centres),))):
        r = d / 2
        x0, x1 = int(np.floor(cx - r - 2)), int(np.ceil(cx + r + 2))
        y0, y1 = int(np.floor(cy - r - 2)), int(np.ceil(cy + r + 2))
        x0c, y0c, x1c, y1c = max(x0, 0), max(y0, 0), min(x1, W - 1), min(y1, H - 1)
        if x1c < x0c or y1c < y0c:
            continue
        px = np.arange(x0c, x1c + 1)[None, :, None, None] + sub[None, None, None, :]
        py = np.arange(y0c, y1c + 1)[:, None, None, None] + sub[None, None, :, None]
        inside = ((px - cx) ** 2 + (py - cy) ** 2 <= r * r).mean(axis=(2, 3))
        cover[y0c : y1c + 1, x0c : x1c + 1] = np.maximum(cover[y0c : y1c + 1, x0c : x1c + 1], inside)
    img = light * (1 - cover) + black * (light / background) * cover
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    img = img + rng.normal(scale=noise, size=img.shape).astype(np.float32)
    if dtype == np.uint8:
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return img


def tube_layout(n=300, radius=4e-3, length=16e-3, seed=0):
    """Reference marker surface coordinates (theta, Z), Poisson-disc-like."""
    p = cylinder_markers(n, radius, length, seed=seed)
    return np.arctan2(p[:, 1], p[:, 0]), p[:, 2]


def tube_surface(theta, Z, radius=4e-3, length=16e-3, radial=1.0, axial=1.0, twist=0.0, bulge=0.0):
    """Deformed wall points (n, 3) and exact outward normals (n, 3) of the analytic tube."""

    def x(t, z):
        r = radius * radial * (1 + bulge * np.cos(np.pi * z / length))
        th = t + twist * z / length
        return np.stack([r * np.cos(th), r * np.sin(th), axial * z], -1)

    h = 1e-7
    dt = (x(theta + h, Z) - x(theta - h, Z)) / (2 * h)
    dz = (x(theta, Z + h) - x(theta, Z - h)) / (2 * h)
    n = np.cross(dt, dz)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return x(theta, Z), n


def projected_series(cams, n_steps=8, n=300, rho=2e-4, noise_px=0.03, n_fake=5, seed=0, radial_step=0.05,
                     axial_step=0.02, twist_step=0.02, bulge_step=0.01, hide=None):
    """Shuffled noisy detections of a deforming marked tube.

    ``hide`` : optional callable (step, vis (n_cams, n)) -> vis to knock out observations.
    Returns (detections[step][cam] (n_i, 2), truth_ids[step][cam] (n_i,) with -1 for fakes,
    centres (n_steps, n, 3), surface (n_steps, n, 3), visible (n_steps, n_cams, n)).
    """
    rng = np.random.default_rng(seed)
    theta, Z = tube_layout(n, seed=seed)
    dets, ids_all, C, S, V = [], [], [], [], []
    for k in range(n_steps):
        s, nrm = tube_surface(theta, Z, radial=1 + radial_step * k, axial=1 + axial_step * k,
                              twist=twist_step * k, bulge=bulge_step * k)
        X = s + rho * nrm
        vis = visible_in(cams, s, nrm)
        if hide is not None:
            vis = hide(k, vis.copy())
        dk, ik = [], []
        for c, cam in enumerate(cams):
            p = cam.project(X[vis[c]]) + rng.normal(size=(int(vis[c].sum()), 2)) * noise_px
            ids = np.flatnonzero(vis[c])
            fake = rng.uniform([0, 0], cam.image_size, (n_fake, 2))
            p = np.vstack([p, fake])
            ids = np.r_[ids, -np.ones(n_fake, int)]
            perm = rng.permutation(len(p))
            dk.append(p[perm])
            ik.append(ids[perm])
        dets.append(dk)
        ids_all.append(ik)
        C.append(X)
        S.append(s)
        V.append(vis)
    return dets, ids_all, np.array(C), np.array(S), np.array(V)
