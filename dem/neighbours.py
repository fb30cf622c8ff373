"""Verlet pair list built with a cell list; contact history carried across rebuilds.

The list holds each pair (i, j > i) once whose gap is below `skin`, in CSR form:
partners of i are partner[start[i]:start[i + 1]]. It stays valid until some grain has moved more
than skin / 2 since the build. Building costs O(N) (counting sort into cells of side
2 r_max + skin over the grains' bounding box), so the whole engine is linear in N.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from dem.kernel_sources import kernel


@kernel()
def _cells(x, radius, skin):
    """Counting sort of the grains x [N, 2] (m) into square cells of side 2 r_max + skin over their
    bounding box: (cell_of [N], cell_start [C+1], in_cell [N] (grains by cell), nx, ny)."""
    n = x.shape[0]
    side = 2.0 * radius.max() + skin
    x_lo, y_lo = x[:, 0].min(), x[:, 1].min()
    nx = int((x[:, 0].max() - x_lo) / side) + 1
    ny = int((x[:, 1].max() - y_lo) / side) + 1
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
    return cell_of, cell_start, in_cell, nx, ny


@kernel()
def _list_rows(i_start, i_end, x, radius, skin, cells, start, partner, old_start, old_partner, old_history, history):
    """Rows i_start <= i < i_end of the pair list over the 3x3 cells around each grain: with
    partner empty, count them into start[i + 1]; else fill partner[start[i]:start[i + 1]] (start
    summed) and carry the history of pairs the old list held. Rows touch only their own slots."""
    cell_of, cell_start, in_cell, nx, ny = cells
    fill = partner.shape[0] > 0
    for i in range(i_start, i_end):
        ci = cell_of[i]
        cx, cy = ci % nx, ci // nx
        cursor = start[i]
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
                        if fill:
                            partner[cursor] = j
                            cursor += 1
                        else:
                            start[i + 1] += 1
        if fill and old_start.shape[0] == x.shape[0] + 1:
            for k in range(start[i], start[i + 1]):
                for m in range(old_start[i], old_start[i + 1]):
                    if old_partner[m] == partner[k]:
                        history[k, :] = old_history[m, :]
                        break


@kernel()
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
    cells = _cells(x, radius, skin)
    start = np.zeros(n + 1, np.int64)
    history = np.zeros((0, old_history.shape[1]))
    _list_rows(0, n, x, radius, skin, cells, start, np.empty(0, np.int64), old_start, old_partner, old_history, history)
    for i in range(n):
        start[i + 1] += start[i]
    partner = np.empty(start[n], np.int64)
    history = np.zeros((start[n], old_history.shape[1]))
    _list_rows(0, n, x, radius, skin, cells, start, partner, old_start, old_partner, old_history, history)
    return start, partner, history


@kernel(parallel=True)
def build_pairs_threaded(
    x: np.ndarray,
    radius: np.ndarray,
    skin: float,
    old_start: np.ndarray,
    old_partner: np.ndarray,
    old_history: np.ndarray,
    bounds: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """build_pairs with the rows of each range bounds[c] <= i < bounds[c + 1] ([n_chunks + 1]) on
    their own thread: the same list, the same bits, whatever the ranges."""
    n, n_chunks = x.shape[0], bounds.shape[0] - 1
    cells = _cells(x, radius, skin)
    start = np.zeros(n + 1, np.int64)
    history = np.zeros((0, old_history.shape[1]))
    for c in nb.prange(n_chunks):
        _list_rows(
            bounds[c],
            bounds[c + 1],
            x,
            radius,
            skin,
            cells,
            start,
            np.empty(0, np.int64),
            old_start,
            old_partner,
            old_history,
            history,
        )
    for i in range(n):
        start[i + 1] += start[i]
    partner = np.empty(start[n], np.int64)
    history = np.zeros((start[n], old_history.shape[1]))
    for c in nb.prange(n_chunks):
        _list_rows(
            bounds[c],
            bounds[c + 1],
            x,
            radius,
            skin,
            cells,
            start,
            partner,
            old_start,
            old_partner,
            old_history,
            history,
        )
    return start, partner, history


HISTORY_WIDTH = 2  # tangential spring (m), rolling torque (N m)


def empty_pairs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An empty old list for the first build."""
    return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, HISTORY_WIDTH))


def default_skin(radius: np.ndarray) -> float:
    """Skin (m) for grain radii `radius` [N] (m): 0.2 mean diameters keeps rebuilds rare without
    bloating the list."""
    return 0.4 * float(np.mean(radius))
