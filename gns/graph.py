"""Radius graph: an edge between every ordered pair of particles closer than the connectivity radius.

Connectivity is a discrete choice, so it is built from detached positions (scipy cKDTree, O(N log N))
and carries no gradient; gradients flow through the edge *features* (relative displacements).
"""

from __future__ import annotations

import logging
import warnings

import numpy as np
import torch
from scipy.spatial import cKDTree

log = logging.getLogger(__name__)


class NeighbourCapWarning(UserWarning):
    """A neighbour cap dropped edges; the message gives how many."""


def radius_graph(
    positions: torch.Tensor, radius: float, graph_index: torch.Tensor | None = None, max_neighbours: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Directed edges (senders [E], receivers [E], int64, on positions.device) between particles
    whose centres are closer than `radius` (same units as positions), no self edges.

    positions [N, 2]; graph_index [N] int (which graph of a batch each node belongs to; no edges
    between graphs), None for one graph. max_neighbours: keep at most this many nearest senders per
    receiver; dropping any edge warns with the count (NeighbourCapWarning), never silently.
    """
    points = positions.detach().cpu().numpy().astype(np.float64)
    if graph_index is None:
        groups = [np.arange(len(points))]
    else:
        gi = graph_index.detach().cpu().numpy()
        groups = [np.flatnonzero(gi == g) for g in np.unique(gi)]
    senders, receivers = [], []
    for nodes in groups:
        pairs = cKDTree(points[nodes]).query_pairs(radius, output_type="ndarray")
        pairs = nodes[pairs] if len(pairs) else np.zeros((0, 2), np.int64)
        senders += [pairs[:, 0], pairs[:, 1]]
        receivers += [pairs[:, 1], pairs[:, 0]]
    senders = np.concatenate(senders).astype(np.int64)
    receivers = np.concatenate(receivers).astype(np.int64)
    if max_neighbours is not None:
        senders, receivers = _cap_neighbours(points, senders, receivers, max_neighbours)
    return (torch.from_numpy(senders).to(positions.device), torch.from_numpy(receivers).to(positions.device))


def _cap_neighbours(points, senders, receivers, max_neighbours):
    """Keep the `max_neighbours` nearest senders of each receiver; warn with the number dropped."""
    distance = np.linalg.norm(points[senders] - points[receivers], axis=1)
    order = np.lexsort((distance, receivers))  # by receiver, then nearest first
    senders, receivers = senders[order], receivers[order]
    first = np.searchsorted(receivers, receivers, side="left")
    rank = np.arange(len(receivers)) - first
    keep = rank < max_neighbours
    dropped = int(np.count_nonzero(~keep))
    if dropped:
        warnings.warn(
            f"radius graph: neighbour cap {max_neighbours} dropped {dropped} of {len(keep)} edges "
            f"({int(np.unique(receivers[~keep]).size)} particles had more neighbours); "
            "raise max_neighbours or lower the connectivity radius",
            NeighbourCapWarning,
            stacklevel=3,
        )
    return senders[keep], receivers[keep]


def graph_summary(n_nodes: int, senders: torch.Tensor) -> dict:
    """Particles per graph and mean edges per node, for logs and metrics."""
    return {
        "particles": int(n_nodes),
        "edges": int(senders.numel()),
        "edges_per_node": float(senders.numel()) / max(int(n_nodes), 1),
    }
