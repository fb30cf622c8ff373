"""Node and edge features of the GNS, each built in a labelled block and concatenated.

Node features follow the paper's eq. (4), x_i = [p_i, pdot_i^{t-C+1..t}, b_i, f_i, params, layout]:
  velocity        [N, 2 (C-1)]  the C - 1 finite-difference velocities of the last C positions
                                 (m per frame), normalised by the training statistics
  walls           [N, 4]         distance to the left, right, bottom and top walls / connectivity
                                 radius, clipped to [-1, 1] (a wall further than the radius reads 1)
  particle_type   [N, E]         a learned embedding (added by the simulator; it owns the weights)
  parameters      [N, P]         DEM parameters (friction, restitution, ...) scaled to [0, 1] over
                                 the dataset's parameter_ranges
  layout          [N, 2]         initial column length L_i and height H_i scaled to [0, 1] likewise
  size            [N, 1]         grain radius / mean grain radius - 1
Edge features follow eq. (5), each block [E, width]:
  displacement    [E, 2]         (p_sender - p_receiver) / connectivity radius
  distance        [E, 1]         its norm
  gap             [E, 1]         the gap between the two grain surfaces / connectivity radius
  parameters      [E, P]         the DEM parameters of the pair's graph, scaled as on the nodes

Where this differs from the paper, and why:
  - no absolute position p_i: it would break translation invariance and lets the network
    memorise where grains sit in the training cases; the wall distances carry what the position
    says about the boundaries (as in Sanchez-Gonzalez et al. 2020, whose code the paper adapted).
  - C positions give C - 1 velocities (the paper writes C velocities from C positions, which
    cannot be formed from C positions without the frame before them).
  - `size` (node) and `gap` (edge) are new: our grains are polydisperse (diameter +-10%), so
    whether a pair touches depends on both sizes, not on the centre distance alone; the gap
    (negative = overlap) states it directly instead of leaving the network to combine centre
    distance and both sizes, which took many more training steps.
  - `parameters` on the edges too (not in the paper): a contact law is a pair force, and the edge
    update is where the network forms it. Fed to the nodes only, a GNS of the cohesive model
    (mu, e, Bond) rolled out the same runout at every Bond number (L*(3.5) 6.3 / 6.2 / 6.4 at Bond
    28 / 44 / 60, DEM 8.3 / 6.5 / 4.4), however it was trained; with the parameters on the edges
    too, the same training gave 8.3 / 7.1 / 6.3 (benchmarks/gns_sensitivity.py, docs/experiments/gns-route.md).
  - degenerate ranges (a parameter fixed across the dataset) give a constant 0 feature.
"""

from __future__ import annotations

import torch

NODE_BLOCKS = ("velocity", "walls", "particle_type", "parameters", "layout", "size")
EDGE_BLOCKS = ("displacement", "distance", "gap", "parameters")


def node_layout(n_input_frames: int, type_embedding_size: int, n_parameters: int) -> list[tuple[str, int]]:
    """[(block name, width)] of the node features in the order they are concatenated."""
    widths = {
        "velocity": 2 * (n_input_frames - 1),
        "walls": 4,
        "particle_type": type_embedding_size,
        "parameters": n_parameters,
        "layout": 2,
        "size": 1,
    }
    return [(name, widths[name]) for name in NODE_BLOCKS]


def edge_layout(n_parameters: int) -> list[tuple[str, int]]:
    """[(block name, width)] of the edge features in the order they are concatenated."""
    widths = {"displacement": 2, "distance": 1, "gap": 1, "parameters": n_parameters}
    return [(name, widths[name]) for name in EDGE_BLOCKS]


def velocity_features(
    position_sequence: torch.Tensor, velocity_mean: torch.Tensor, velocity_std: torch.Tensor
) -> torch.Tensor:
    """position_sequence [N, C, 2] (m) -> normalised velocities [N, 2 (C-1)]; velocity_mean and
    velocity_std [2] (m per frame)."""
    velocity = position_sequence[:, 1:] - position_sequence[:, :-1]  # m per frame
    return ((velocity - velocity_mean) / velocity_std).flatten(1)


def wall_features(position: torch.Tensor, bounds: torch.Tensor, connectivity_radius_m: float) -> torch.Tensor:
    """position [N, 2] (m), bounds [2, 2] ((x_min, x_max), (y_min, y_max)) -> [N, 4]:
    distances to left, right, bottom, top walls / radius, clipped to [-1, 1]."""
    lower = position - bounds[:, 0]
    upper = bounds[:, 1] - position
    distance = torch.stack([lower[:, 0], upper[:, 0], lower[:, 1], upper[:, 1]], dim=1)
    return torch.clamp(distance / connectivity_radius_m, -1.0, 1.0)


def scaled(values: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """values [..., P] scaled to [0, 1] over [low, high] (each [P]); a degenerate range gives 0."""
    span = high - low
    safe = torch.where(span > 0, span, torch.ones_like(span))
    return torch.where(span > 0, (values - low) / safe, torch.zeros_like(values))


def size_features(radius: torch.Tensor, mean_radius: float) -> torch.Tensor:
    """radius [N] (m) -> [N, 1] relative deviation from the mean grain radius `mean_radius` (m)."""
    return (radius / mean_radius - 1.0)[:, None]


def pair_geometry(
    position: torch.Tensor,
    grain_radius: torch.Tensor,
    senders: torch.Tensor,
    receivers: torch.Tensor,
    connectivity_radius_m: float,
) -> dict[str, torch.Tensor]:
    """position [N, 2] (m), grain_radius [N] (m), senders and receivers [E] int64 node indices ->
    the edge blocks {displacement [E, 2], distance [E, 1], gap [E, 1]}: displacement sender -
    receiver, its norm, and the surface gap |d| - r_s - r_r, all / connectivity radius (m)."""
    displacement = (position[senders] - position[receivers]) / connectivity_radius_m
    # the norm's gradient is undefined at 0; no self edges, but coincident grains must not give NaN
    distance = torch.sqrt(torch.sum(displacement**2, dim=-1, keepdim=True) + 1e-12)
    gap = distance - ((grain_radius[senders] + grain_radius[receivers]) / connectivity_radius_m)[:, None]
    return {"displacement": displacement, "distance": distance, "gap": gap}
