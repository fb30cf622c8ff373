"""Small synthetic trajectories for the GNS tests, in closed form: half the grains rest on the floor
and slide with an initial speed until Coulomb friction (deceleration mu g) stops them; the other
half fly above them under gravity and do not land within the trajectory. No grains touch. The
motion depends on mu and on the distance to the floor (restitution is carried as a parameter but
does not act: nothing collides)."""

from __future__ import annotations

import numpy as np

from dem.trajectory import Trajectory, write_trajectory
from gns.dataset import build_dataset

BOX = (0.2, 0.1)  # m, width and height
DT_FRAME = 0.004  # s
RADIUS = 0.002  # m, mean
GRAVITY = 9.81


def sliding_grains(
    friction: float,
    restitution: float,
    n_frames: int = 24,
    n_grains: int = 12,
    seed: int = 0,
    L_i: float = 0.03,
    H_i: float = 0.04,
) -> Trajectory:
    rng = np.random.default_rng(seed)
    radius = RADIUS * rng.uniform(0.9, 1.1, n_grains)
    x0 = np.sort(rng.uniform(0.0, L_i, n_grains)) + 3 * RADIUS * np.arange(n_grains)
    speed = rng.uniform(0.1, 0.4, n_grains)
    deceleration = friction * GRAVITY
    t = np.arange(n_frames)[:, None] * DT_FRAME
    t_stop = speed / deceleration
    moving = np.minimum(t, t_stop)
    x = x0 + speed * moving - 0.5 * deceleration * moving**2
    y = np.broadcast_to(radius, x.shape).copy()
    flying = np.arange(n_grains) % 2 == 1
    x[:, flying] = x0[flying] + speed[flying] * t
    y[:, flying] = rng.uniform(0.06, 0.09, flying.sum()) - 0.5 * GRAVITY * t**2
    positions = np.stack([x, y], axis=-1)
    attrs = {
        "engine": "synthetic",
        "engine_version": "1",
        "L_i": L_i,
        "H_i": H_i,
        "aspect_ratio": H_i / L_i,
        "material": "quartz",
        "dt_frame": DT_FRAME,
        "t_star": float(np.sqrt(H_i / GRAVITY)),
        "x_min": 0.0,
        "x_max": BOX[0],
        "y_min": 0.0,
        "y_max": BOX[1],
        "seed": seed,
        "friction": friction,
        "restitution": restitution,
    }
    return Trajectory(positions.astype(np.float32), radius, np.zeros(n_grains, np.int32), attrs)


def synthetic_dataset(folder, n_train: int = 4, n_frames: int = 24) -> str:
    """Write train/valid/test trajectories and the dataset metadata; returns the metadata path."""
    cases = {
        "train": [(0.2 + 0.5 * k / max(n_train - 1, 1), 0.5 + 0.3 * (k % 2)) for k in range(n_train)],
        "valid": [(0.45, 0.6)],
        "test": [(0.5, 0.7)],
    }
    splits = {}
    for split, params in cases.items():
        splits[split] = []
        for k, (mu, e) in enumerate(params):
            path = f"{folder}/{split}_{k}.h5"
            write_trajectory(path, sliding_grains(mu, e, n_frames=n_frames, seed=len(splits) * 10 + k))
            splits[split].append(path)
    out = f"{folder}/metadata.json"
    build_dataset(splits, out, "synthetic")
    return out
