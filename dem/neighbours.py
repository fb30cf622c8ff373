"""Verlet pair list built with a cell list; contact history carried across rebuilds.

The list holds each pair (i, j > i) once whose gap is below `skin`, in CSR form:
partners of i are partner[start[i]:start[i + 1]]. It stays valid until some grain has moved more
than skin / 2 since the build. Building costs O(N) (counting sort into cells of side
2 r_max + skin over the grains' bounding box), so the whole engine is linear in N.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def build_pairs(
    x: np.ndarray,
    radius: np.ndarray,
    skin: float,
    old_start: np.ndarray,
    old_partner: np.ndarray,
    old_history: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """New CSR pair list (start [N+1], partner [M]) and history [M, H] carried from the old list.

    x [N, 2] positions (m), radius [N] (m), skin (m); old_* the previous list (old_start [N+1] int64,
    old_partner [M_old] int64, old_history [M_old, H]; empty arrays when none, see empty_pairs). A
    pair absent from the old list starts with relaxed springs (zero history).
    """
    n = x.shape[0]
    r_max = radius.max()
    side = 2.0 * r_max + skin
    x_lo, y_lo = x[:, 0].min(), x[:, 1].min()
    nx = int((x[:, 0].max() - x_lo) / side) + 1
    ny = int((x[:, 1].max() - y_lo) / side) + 1
    # counting sort of grains into cells
    cell_of = np.empty(n, np.int64)
    cell_start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        c = int((x[i, 1] - y_lo) / side) * nx + int((x[i, 0] - x_lo) / side)
        cell_of[i] = c
        cell_start[c + 1] += 1
    for c in range(nx * ny):
        cell_start[c + 1] += cell_start[c]
    fill = cell_start[:-1].copy()
    in_cell = np.empty(n, np.int64)
    for i in range(n):
        in_cell[fill[cell_of[i]]] = i
        fill[cell_of[i]] += 1
    # two passes over the 3x3 cell neighbourhood: count, then fill
    start = np.zeros(n + 1, np.int64)
    partner = np.empty(0, np.int64)
    for fill_pass in range(2):
        if fill_pass == 1:
            for i in range(n):
                start[i + 1] += start[i]
            partner = np.empty(start[n], np.int64)
            cursor = start[:-1].copy()
        for i in range(n):
            ci = cell_of[i]
            cx, cy = ci % nx, ci // nx
            for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
                    c = gy * nx + gx
                    for k in range(cell_start[c], cell_start[c + 1]):
                        j = in_cell[k]
                        if j <= i:
                            continue
                        dx = x[j, 0] - x[i, 0]
                        dy = x[j, 1] - x[i, 1]
                        reach = radius[i] + radius[j] + skin
                        if dx * dx + dy * dy < reach * reach:
                            if fill_pass == 0:
                                start[i + 1] += 1
                            else:
                                partner[cursor[i]] = j
                                cursor[i] += 1
    # carry the history of pairs that were already listed
    history = np.zeros((partner.shape[0], old_history.shape[1]))
    if old_start.shape[0] == n + 1:
        for i in range(n):
            for k in range(start[i], start[i + 1]):
                for m in range(old_start[i], old_start[i + 1]):
                    if old_partner[m] == partner[k]:
                        history[k, :] = old_history[m, :]
                        break
    return start, partner, history


HISTORY_WIDTH = 2  # tangential spring (m), rolling torque (N m)


def empty_pairs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An empty old list for the first build."""
    return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, HISTORY_WIDTH))


def default_skin(radius: np.ndarray) -> float:
    """Skin (m) for grain radii `radius` [N] (m): 0.2 mean diameters keeps rebuilds rare without
    bloating the list."""
    return 0.4 * float(np.mean(radius))
