"""Level sets of V(Ψ(x) − Ψ(x_eq)) drawn in x-space (n = 2): for each direction from x_eq, the first radius
where V reaches the level (bisection after a coarse scan)."""
from __future__ import annotations

import numpy as np


def level_set_boundary(model, lyap, level: float, *, radius: float = 3.0, n_angles: int = 180,
                       n_scan: int = 200) -> np.ndarray:
    """Points (n_angles, 2) on {x : V(z(x)) = level}; directions where V stays below the level within
    ``radius`` are left out.  Empty for n ≠ 2 or a non-positive level."""
    if model.n != 2 or not level > 0 or not np.isfinite(level):
        return np.zeros((0, 2))
    ang = np.linspace(0, 2 * np.pi, n_angles, endpoint=False)
    dirs = np.stack([np.cos(ang), np.sin(ang)], 1)
    rho = np.linspace(0, radius, n_scan)[1:]
    pts = model.x_eq + dirs[:, None, :] * rho[None, :, None]
    V = lyap.value(model.lift(pts.reshape(-1, 2))).reshape(n_angles, -1)
    # bisection on every crossing direction at once (one batched lift per halving, not one per point)
    hit = V >= level
    rows = np.flatnonzero(hit.any(axis=1))
    j = hit[rows].argmax(axis=1)
    lo = np.where(j == 0, 0.0, rho[np.maximum(j - 1, 0)])
    hi = rho[j]
    d = dirs[rows]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        above = lyap.value(model.lift(model.x_eq + mid[:, None] * d)) >= level
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return (model.x_eq + (0.5 * (lo + hi))[:, None] * d).reshape(-1, 2)
