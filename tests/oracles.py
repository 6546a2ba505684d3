"""Plain numpy reference implementations the compiled kernels are checked against (and benchmarked on)."""
from __future__ import annotations

import numpy as np


def play_response_numpy(r: np.ndarray, x: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1) as a plain per-sample numpy loop: every operator's output (N x n) and the final states."""
    r = np.asarray(r, dtype=np.float64)
    y = np.asarray(state, dtype=np.float64).copy()
    out = np.empty((len(x), len(r)))
    for k, xk in enumerate(np.asarray(x, dtype=np.float64)):
        y = np.maximum(xk - r, np.minimum(xk + r, y))
        out[k] = y
    return out, y


def generalized_play_numpy(r: np.ndarray, down_scale: np.ndarray, x: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Generalized play operators (descending threshold ``r * down_scale[k]``): outputs (N x n)."""
    y = np.asarray(state, dtype=np.float64).copy()
    out = np.empty((len(x), len(r)))
    for k, xk in enumerate(np.asarray(x, dtype=np.float64)):
        y = np.maximum(xk - r, np.minimum(xk + r * down_scale[k], y))
        out[k] = y
    return out


def dead_zone_numpy(h: np.ndarray, g: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Kuhnen's superposition of one-sided dead-zone operators, ``sum_j g_j S_{h_j}(z)``, element-wise in z."""
    z = np.asarray(z, dtype=np.float64)[..., None]
    d = np.where(h > 0, np.maximum(z - h, 0.0), np.where(h < 0, np.minimum(z - h, 0.0), z))
    return d @ g
