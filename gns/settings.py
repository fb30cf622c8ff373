"""The GNS training settings (the config's `gns` section) and the model config they make with a
dataset's geometry and statistics: what gns/train.py trains and a checkpoint records."""

from __future__ import annotations

from dataclasses import dataclass

from dem.fields import from_mapping
from gns.simulator import SimulatorConfig


@dataclass
class TrainSettings:
    """The config's `gns` section (workflow/schemas/config.schema.yaml documents each key)."""

    # A small model, sized by measurement on the quartz a = 6 column (589 grains, one step =
    # 0.005 s; benchmarks/gns_speed.py, docs/experiments/gns-training.md): a rollout step costs several times less
    # than the 64-wide, M = 5 model and trains ~4x more steps per CPU second.
    connectivity_radius: float = 2.0  # in mean grain diameters of the dataset (~10 edges per grain)
    n_input_frames: int = 6  # C
    latent_size: int = 32
    mlp_hidden_layers: int = 2
    n_message_passing: int = 3  # M
    type_embedding_size: int = 16
    max_neighbours: int | None = None
    wall_clamp: bool = True  # rollouts keep grains out of the walls (LearnedSimulator.keep_inside_walls)
    noise_std: float = (
        0.0015  # mean grain diameters per frame, on the last input velocity (0.005: test runout MSE 1.5, 0.0015: 1.07)
    )
    pushforward_steps: int = 2  # own no-gradient steps before a pushforward step's loss (0: never)
    pushforward_fraction: float = 0.5  # fraction of training steps that use the pushforward loss
    steps: int = 12000  # with pushforward; the validation runout MSE levels off near here
    batch_size: int = 2  # windows (graphs) per step
    learning_rate: float = 1e-3
    learning_rate_final: float = 1e-5
    learning_rate_decay_steps: int = 10000  # lr falls by 10x over this many steps towards the final (5000 with
    # pushforward: valid runout MSE 8.9 at 8000 steps instead of 0.25)
    ema_decay: float = 0.99  # validated and saved model: exponential moving average of the
    # weights (0: the raw weights); smooths step-to-step jitter
    validate_every: int = 1000
    validation_windows: int = 16
    validation_rollouts: int = 8  # valid trajectories rolled out per validation (evenly picked)
    checkpoint_every: int = 100
    log_every: int = 50
    seed: int = 0
    device: str = "auto"  # "auto": cuda when present, else cpu
    # warm start: a trained GNS (model_best.pt) whose weights this one starts from (gns.simulator.warm_start),
    # e.g. the base model's GNS of the same column for the GNS of an extended model; None: random weights
    init_from: str | None = None

    def __post_init__(self):
        if self.pushforward_steps < 0 or not 0.0 <= self.pushforward_fraction <= 1.0:
            raise ValueError(
                f"config gns: pushforward_steps must be >= 0 and pushforward_fraction in [0, 1], got "
                f"{self.pushforward_steps} and {self.pushforward_fraction}"
            )

    @classmethod
    def from_config(cls, section: dict | None) -> TrainSettings:
        return from_mapping(cls, dict(section or {}), ValueError, "config gns")

    def learning_rate_at(self, step: int) -> float:
        """lr(step) = (lr0 - lr_final) 0.1^(step / decay_steps) + lr_final (Sanchez-Gonzalez et al.)."""
        decay = 0.1 ** (step / self.learning_rate_decay_steps)
        return (self.learning_rate - self.learning_rate_final) * decay + self.learning_rate_final


def simulator_config(metadata: dict, settings: TrainSettings) -> SimulatorConfig:
    """Model config from the dataset's geometry and statistics and the training settings."""
    diameter = float(metadata["material_diameter"])
    return SimulatorConfig(
        connectivity_radius_m=settings.connectivity_radius * diameter,
        bounds=[[float(v) for v in b] for b in metadata["bounds"]],
        parameter_ranges={k: [float(v) for v in r] for k, r in metadata["parameter_ranges"].items()},
        mean_radius=0.5 * diameter,
        dt_frame=float(metadata["dt_frame"]),
        velocity_mean=list(map(float, metadata["velocity_mean"])),
        velocity_std=list(map(float, metadata["velocity_std"])),
        acceleration_mean=list(map(float, metadata["acceleration_mean"])),
        acceleration_std=list(map(float, metadata["acceleration_std"])),
        noise_std_m=settings.noise_std * diameter,
        n_input_frames=settings.n_input_frames,
        latent_size=settings.latent_size,
        mlp_hidden_layers=settings.mlp_hidden_layers,
        n_message_passing=settings.n_message_passing,
        type_embedding_size=settings.type_embedding_size,
        max_neighbours=settings.max_neighbours,
        wall_clamp=settings.wall_clamp,
    )
