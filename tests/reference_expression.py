"""An independent float64 NumPy reference of SPEC §1, written straight from the formulas.

It deliberately shares nothing with ``warpface.expression``: angles via arccos (the kernels use
atan2), every muscle evaluated densely (the model precomputes sparse weights), Bézier distances by
dense sampling + golden-section refinement (the model uses Newton), every wrinkle summed over every
vertex (the model drops negligible entries), and scatter-adds (the model gathers).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def linear_muscle(points, v1, v2, zone_deg, rs, rf, k):
    offset = points - v1
    distance = np.linalg.norm(offset, axis=1)
    axis = (v2 - v1) / np.linalg.norm(v2 - v1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_mu = np.clip((offset @ axis) / distance, -1.0, 1.0)
    mu = np.arccos(cos_mu)
    zone = np.radians(zone_deg)
    affected = (distance > 0) & (distance <= rf) & (mu <= zone)
    angular = np.cos(mu / zone * np.pi / 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        radial = np.where(
            distance < rs, np.cos((1 - distance / rs) * np.pi / 2), np.cos((distance - rs) / (rf - rs) * np.pi / 2)
        )
        direction = -offset / distance[:, None]
    out = np.zeros_like(points)
    out[affected] = (k * angular * radial)[affected, None] * direction[affected]
    return out


def sphincter_muscle(points, center, ex, ey, lx, ly, k):
    ex = ex / np.linalg.norm(ex)
    ey = ey - (ey @ ex) * ex
    ey = ey / np.linalg.norm(ey)
    offset = points - center
    x, y = offset @ ex, offset @ ey
    f = 1 - np.sqrt(x**2 / lx**2 + y**2 / ly**2)
    out = -k * f[:, None] * (x[:, None] * ex + y[:, None] * ey)
    out[f <= 0] = 0.0
    return out


def lid_hinge(points, centre, axis, vertices, angles, slides, lifts, k):
    """A lid hinge's displacement at contraction ``k`` (docs/RIG.md §11), by Rodrigues' formula: each listed
    vertex turned by ``angle`` about ``axis`` through ``centre``, lifted along the turned point's unit offset
    from the axis and slid along the axis — all times ``k`` (the field is linear in k)."""
    a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    out = np.zeros_like(points)
    for v, angle, slide, lift in zip(vertices, angles, slides, lifts):
        r = points[v] - centre
        turned = r * np.cos(angle) + np.cross(a, r) * np.sin(angle) + a * (a @ r) * (1.0 - np.cos(angle))
        radial = turned - (turned @ a) * a
        outward = radial / np.linalg.norm(radial) if np.linalg.norm(radial) > 0 else radial
        out[v] = k * (turned + centre + lift * outward + slide * a - points[v])
    return out


def triangle_areas(points, triangles):
    p = points[triangles]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def vertex_normals(points, triangles):
    p = points[triangles]
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals = np.zeros_like(points)
    for corner in range(3):
        np.add.at(normals, triangles[:, corner], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def stretch_ratio(rest, deformed, triangles):
    ratio = triangle_areas(deformed, triangles) / triangle_areas(rest, triangles)
    total = np.zeros(len(rest))
    count = np.zeros(len(rest))
    for corner in range(3):
        np.add.at(total, triangles[:, corner], ratio)
        np.add.at(count, triangles[:, corner], 1.0)
    return np.where(count > 0, total / np.maximum(count, 1), 1.0)


def project(points, projection):
    offset = points - projection["origin"]
    if projection["kind"] == "planar":
        u = projection["u"] / np.linalg.norm(projection["u"])
        v = projection["v"] / np.linalg.norm(projection["v"])
        return np.c_[offset @ u, offset @ v]
    axis = projection["axis"] / np.linalg.norm(projection["axis"])
    ref = projection["reference"] - (projection["reference"] @ axis) * axis
    ref = ref / np.linalg.norm(ref)
    side = np.cross(axis, ref)
    theta = np.arctan2(offset @ side, offset @ ref)
    return np.c_[projection["radius"] * theta, offset @ axis]


def bezier(control, t):
    s = 1 - t
    return (
        (s**3)[:, None] * control[0]
        + (3 * s * s * t)[:, None] * control[1]
        + (3 * s * t * t)[:, None] * control[2]
        + (t**3)[:, None] * control[3]
    )


def bezier_distance(uv, control, samples: int = 20001):
    t = np.linspace(0.0, 1.0, samples)
    _, nearest = cKDTree(bezier(control, t)).query(uv)
    lo = np.clip(t[nearest] - 1.0 / (samples - 1), 0, 1)
    hi = np.clip(t[nearest] + 1.0 / (samples - 1), 0, 1)
    golden = (np.sqrt(5) - 1) / 2
    for _ in range(60):
        a = hi - golden * (hi - lo)
        b = lo + golden * (hi - lo)
        da = np.linalg.norm(bezier(control, a) - uv, axis=1)
        db = np.linalg.norm(bezier(control, b) - uv, axis=1)
        hi = np.where(da < db, b, hi)
        lo = np.where(da < db, lo, a)
    return np.linalg.norm(bezier(control, 0.5 * (lo + hi)) - uv, axis=1)


def shape(d, kd, kw):
    return kd * (d / kw - 1) * np.exp(-d / kw)


def contraction_factor(r, kr):
    if kr == 0:
        return np.where(r <= 1, 1 - r, 0.0)
    return np.where(r <= 1, (kr - 1) * r + 1, kr * np.exp((1 - 1 / kr) * (r - 1)))


def evaluate(rest, triangles, muscles, contractions, wrinkles, thickness):
    """Stages of SPEC §1 in float64. ``muscles``/``wrinkles`` are dicts (see the tests)."""
    x1 = rest.copy()
    for muscle, k in zip(muscles, contractions):
        if muscle["kind"] == "linear":
            x1 += linear_muscle(rest, muscle["v1"], muscle["v2"], muscle["zone"], muscle["rs"], muscle["rf"], k)
        else:
            x1 += sphincter_muscle(rest, muscle["center"], muscle["ex"], muscle["ey"], muscle["lx"], muscle["ly"], k)
    r = stretch_ratio(rest, x1, triangles)
    x2 = x1 + ((1 / r - 1) * thickness)[:, None] * vertex_normals(x1, triangles)
    n2 = vertex_normals(x2, triangles)
    height = np.zeros(len(rest))
    for wrinkle in wrinkles:
        d = bezier_distance(project(rest, wrinkle["projection"]), wrinkle["control"])
        height += shape(d, wrinkle["kd"], wrinkle["kw"]) * contraction_factor(r, wrinkle["kr"])
    x3 = x2 + height[:, None] * n2
    return {"muscle": x1, "stretch": r, "bulge": x2, "final": x3}
