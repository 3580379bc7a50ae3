"""Affine 4x4 transforms with Mitsuba's conventions (column vectors, later operations on the left)."""
import numpy as np


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def scale(v) -> np.ndarray:
    return np.diag([*np.broadcast_to(np.asarray(v, float), 3), 1.0])


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Right-handed rotation about `axis` (Rodrigues' formula)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * k + (1 - c) * np.outer(a, a)
    return m


def lookat(origin, target, up) -> np.ndarray:
    """Camera-to-world: local +z looks at the target, +y is up and +x points left, as in Mitsuba."""
    o, t, u = (np.asarray(x, float) for x in (origin, target, up))
    direction = t - o
    direction /= np.linalg.norm(direction)
    left = np.cross(u, direction)
    left /= np.linalg.norm(left)
    new_up = np.cross(direction, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, direction, o
    return m


def apply_point(m: np.ndarray, p) -> np.ndarray:
    p = np.atleast_2d(np.asarray(p, float))
    return p @ m[:3, :3].T + m[:3, 3]


def apply_vector(m: np.ndarray, v) -> np.ndarray:
    return np.atleast_2d(np.asarray(v, float)) @ m[:3, :3].T


def apply_normal(m: np.ndarray, n) -> np.ndarray:
    """Normals transform by the inverse transpose; the result is normalised."""
    out = np.atleast_2d(np.asarray(n, float)) @ np.linalg.inv(m[:3, :3])
    return out / np.linalg.norm(out, axis=1, keepdims=True)
