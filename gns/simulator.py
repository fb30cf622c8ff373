"""The learned simulator: preprocess (features) -> network -> postprocess (semi-implicit Euler).

Units: positions in m, time in frames of the dataset (dt_frame s). Velocities are m per frame
(x[t] - x[t-1]) and accelerations m per frame^2 (x[t+1] - 2 x[t] + x[t-1]); the network predicts
the acceleration normalised by the training statistics, and `inverse_postprocess` turns the next
position back into that normalised acceleration, the training target.

Everything that depends on the physical setting (bounds, parameter ranges, statistics, radius)
lives in `SimulatorConfig`, saved in every checkpoint, so a checkpoint rebuilds its own model and
refuses data it was not trained for (`check_compatible`).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import torch
from torch import nn

from dem.fields import from_mapping
from gns import features
from gns.dataset import LAYOUT_KEYS
from gns.graph import radius_graph
from gns.memory import keep_freed_memory
from gns.network import EncodeProcessDecode

# entries of a dataset's parameter_ranges that are not DEM parameters: the layout, and the
# aspect ratio H_i / L_i that the layout already gives
NOT_PARAMETERS = LAYOUT_KEYS + ("aspect_ratio",)
# checkpoint keys of older trainings, renamed: the metres carry their unit (the config's keys are in diameters)
RENAMED = {"connectivity_radius": "connectivity_radius_m", "noise_std": "noise_std_m"}
WALL_CLAMP_DEPTH = 0.5  # grain radii: the deepest a rollout lets a grain centre sink into a wall


class CheckpointError(ValueError):
    """A checkpoint does not fit the code or the data it is used with; the message says how."""


@dataclass
class SimulatorConfig:
    """Everything needed to rebuild a simulator (stored in checkpoints as a plain dict)."""

    connectivity_radius_m: float  # m
    bounds: list  # [[x_min, x_max], [y_min, y_max]] (m)
    parameter_ranges: dict  # name -> [min, max]: DEM parameters and L_i, H_i
    mean_radius: float  # m, mean grain radius of the dataset
    dt_frame: float  # s per GNS step
    velocity_mean: list  # [2] m/frame
    velocity_std: list  # [2] m/frame
    acceleration_mean: list  # [2] m/frame^2
    acceleration_std: list  # [2] m/frame^2
    noise_std_m: float = 0.0  # m/frame, training input noise (combined into stats)
    n_input_frames: int = 6  # C
    latent_size: int = 128
    mlp_hidden_layers: int = 2
    n_message_passing: int = 5  # M
    n_particle_types: int = 1
    type_embedding_size: int = 16
    max_neighbours: int | None = None
    wall_clamp: bool = True  # rollouts: project grains back out of the walls (see keep_inside_walls)
    node_layout: list = field(default_factory=list)  # filled in by __post_init__
    edge_layout: list = field(default_factory=list)

    def __post_init__(self):
        for key in ("velocity_std", "acceleration_std"):
            if len(getattr(self, key)) != 2 or min(getattr(self, key)) < 0:
                raise CheckpointError(
                    f"simulator config: {key} must be two non-negative numbers, got {getattr(self, key)}"
                )
        missing = [k for k in LAYOUT_KEYS if k not in self.parameter_ranges]
        if missing:
            raise CheckpointError(f"simulator config: parameter_ranges lacks the layout entries {missing}")
        if self.n_input_frames < 2:
            raise CheckpointError(f"simulator config: n_input_frames (C) must be >= 2, got {self.n_input_frames}")
        layout = [
            list(b)
            for b in features.node_layout(self.n_input_frames, self.type_embedding_size, len(self.parameter_names))
        ]
        edge = [list(b) for b in features.edge_layout(len(self.parameter_names))]
        if self.node_layout and [list(b) for b in self.node_layout] != layout:
            raise CheckpointError(
                f"feature layout mismatch: checkpoint has node features {self.node_layout}, "
                f"this code builds {layout}; retrain the model"
            )
        if self.edge_layout and [list(b) for b in self.edge_layout] != edge:
            raise CheckpointError(
                f"feature layout mismatch: checkpoint has edge features {self.edge_layout}, "
                f"this code builds {edge}; retrain the model"
            )
        self.node_layout, self.edge_layout = layout, edge

    @property
    def parameter_names(self) -> list[str]:
        """DEM parameters fed to the network: parameter_ranges but L_i, H_i and aspect_ratio."""
        return [k for k in self.parameter_ranges if k not in NOT_PARAMETERS]

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> SimulatorConfig:
        return from_mapping(cls, data, CheckpointError, "simulator config (written by another version?)", RENAMED)

    def check_compatible(self, metadata: dict, where: str = "dataset") -> None:
        """Raise CheckpointError when the dataset's parameters, frame interval or bounds differ."""
        names = [k for k in metadata["parameter_ranges"] if k not in NOT_PARAMETERS]
        if names != self.parameter_names:
            raise CheckpointError(
                f"{where}: parameter set {names} differs from the checkpoint's "
                f"{self.parameter_names}; retrain for these parameters"
            )
        if abs(float(metadata["dt_frame"]) - self.dt_frame) > 1e-9 * self.dt_frame:
            raise CheckpointError(
                f"{where}: dt_frame {metadata['dt_frame']} s differs from the checkpoint's "
                f"{self.dt_frame} s (one GNS step is one frame)"
            )
        if [[float(v) for v in b] for b in metadata["bounds"]] != [[float(v) for v in b] for b in self.bounds]:
            raise CheckpointError(f"{where}: bounds {metadata['bounds']} differ from the checkpoint's {self.bounds}")


@dataclass
class Context:
    """What a rollout holds fixed: particle_type [N] int64, radius [N] (m), parameters [G, P]
    (physical units, in config.parameter_names order), layout [G, 2] (L_i, H_i in m) and
    graph_index [N] int64 (graph of each node, for batches of G graphs)."""

    particle_type: torch.Tensor
    radius: torch.Tensor
    parameters: torch.Tensor
    layout: torch.Tensor
    graph_index: torch.Tensor

    @classmethod
    def single(
        cls, particle_type: torch.Tensor, radius: torch.Tensor, parameters: torch.Tensor, layout: torch.Tensor
    ) -> Context:
        """The context of one graph: particle_type [N] (any integer or float dtype; cast to int64),
        radius [N] (m), parameters [P] and layout [2] (each reshaped to one row)."""
        n = len(radius)
        return cls(
            torch.as_tensor(particle_type, dtype=torch.long),
            radius,
            parameters.reshape(1, -1),
            layout.reshape(1, -1),
            torch.zeros(n, dtype=torch.long, device=radius.device),
        )

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Context:
        floats = {k: getattr(self, k).to(device=device, dtype=dtype) for k in ("radius", "parameters", "layout")}
        return Context(self.particle_type.to(device), graph_index=self.graph_index.to(device), **floats)


class LearnedSimulator(nn.Module):
    def __init__(self, config: SimulatorConfig):
        super().__init__()
        keep_freed_memory()  # every GNS process builds one: its steps then reuse their freed activations
        self.config = config
        c = config
        node_in = sum(width for _, width in c.node_layout)
        edge_in = sum(width for _, width in c.edge_layout)
        self.network = EncodeProcessDecode(
            node_in, edge_in, 2, c.latent_size, c.latent_size, c.mlp_hidden_layers, c.n_message_passing
        )
        self.type_embedding = nn.Embedding(c.n_particle_types, c.type_embedding_size)
        # Sanchez-Gonzalez et al.: the input noise widens the statistics the inputs and targets
        # are normalised with, so that noisy inputs stay O(1) after normalisation.
        noise = torch.tensor(c.noise_std_m, dtype=torch.float64)
        combine = lambda std: torch.sqrt(torch.tensor(std, dtype=torch.float64) ** 2 + noise**2)  # noqa: E731
        self.register_buffer("velocity_mean", torch.tensor(c.velocity_mean, dtype=torch.float32))
        self.register_buffer("velocity_std", combine(c.velocity_std).float())
        self.register_buffer("acceleration_mean", torch.tensor(c.acceleration_mean, dtype=torch.float32))
        self.register_buffer("acceleration_std", combine(c.acceleration_std).float())
        self.register_buffer("bounds", torch.tensor(c.bounds, dtype=torch.float32))
        ranges = torch.tensor([c.parameter_ranges[k] for k in c.parameter_names], dtype=torch.float32).reshape(-1, 2)
        layout = torch.tensor([c.parameter_ranges[k] for k in LAYOUT_KEYS], dtype=torch.float32)
        self.register_buffer("parameter_low", ranges[:, 0])
        self.register_buffer("parameter_high", ranges[:, 1])
        self.register_buffer("layout_low", layout[:, 0])
        self.register_buffer("layout_high", layout[:, 1])

    # -- preprocess ------------------------------------------------------------------------------
    def preprocess(
        self, position_sequence: torch.Tensor, context: Context
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """position_sequence [N, C, 2] (m) -> (node features [N, F_v], edge features [E, F_e],
        senders [E], receivers [E]); blocks in config.node_layout and config.edge_layout order."""
        c = self.config
        if position_sequence.shape[1] != c.n_input_frames:
            raise ValueError(
                f"position_sequence has {position_sequence.shape[1]} frames, the model takes C = {c.n_input_frames}"
            )
        if int(context.particle_type.max()) >= c.n_particle_types:
            raise ValueError(
                f"particle_type {int(context.particle_type.max())} unknown to this model "
                f"(trained with {c.n_particle_types} type(s))"
            )
        position = position_sequence[:, -1]
        senders, receivers = radius_graph(position, c.connectivity_radius_m, context.graph_index, c.max_neighbours)
        per_node = context.graph_index
        parameters = features.scaled(context.parameters, self.parameter_low, self.parameter_high)  # [G, P]
        blocks = {
            "velocity": features.velocity_features(position_sequence, self.velocity_mean, self.velocity_std),
            "walls": features.wall_features(position, self.bounds, c.connectivity_radius_m),
            "particle_type": self.type_embedding(context.particle_type),
            "parameters": parameters[per_node],
            "layout": features.scaled(context.layout, self.layout_low, self.layout_high)[per_node],
            "size": features.size_features(context.radius, c.mean_radius),
        }
        node_features = torch.cat([blocks[name].to(position.dtype) for name, _ in c.node_layout], dim=-1)
        edge_blocks = {
            **features.pair_geometry(position, context.radius, senders, receivers, c.connectivity_radius_m),
            "parameters": parameters[per_node[receivers]],  # a pair lies in one graph
        }
        edge_features = torch.cat([edge_blocks[name].to(position.dtype) for name, _ in c.edge_layout], dim=-1)
        return node_features, edge_features, senders, receivers

    def forward(self, position_sequence: torch.Tensor, context: Context) -> torch.Tensor:
        """Normalised acceleration [N, 2] of the last frame of position_sequence [N, C, 2]."""
        return self.network(*self.preprocess(position_sequence, context))

    # -- postprocess and its inverse -------------------------------------------------------------
    def postprocess(self, normalised_acceleration: torch.Tensor, position_sequence: torch.Tensor) -> torch.Tensor:
        """Semi-implicit Euler over one frame: v' = v + a, x' = x + v' (m, m/frame) -> next position [N, 2].

        normalised_acceleration [N, 2]; position_sequence [N, C, 2] (m)."""
        acceleration = normalised_acceleration * self.acceleration_std + self.acceleration_mean
        velocity = position_sequence[:, -1] - position_sequence[:, -2]
        return position_sequence[:, -1] + velocity + acceleration

    def inverse_postprocess(self, next_position: torch.Tensor, position_sequence: torch.Tensor) -> torch.Tensor:
        """The normalised acceleration [N, 2] that `postprocess` turns into next_position [N, 2] (m),
        given position_sequence [N, C, 2] (m)."""
        velocity = position_sequence[:, -1] - position_sequence[:, -2]
        acceleration = (next_position - position_sequence[:, -1]) - velocity
        return (acceleration - self.acceleration_mean) / self.acceleration_std

    def keep_inside_walls(self, position: torch.Tensor, radius: torch.Tensor) -> torch.Tensor:
        """Project grain centres that sank more than half a radius into the floor or the side walls
        back to that depth (position [N, 2], radius [N], m).

        Not in the paper: a briefly trained GNS lets a grain under the column's weight creep into
        the floor until the rollout leaves the box. No DEM frame comes near this depth (overlaps
        there are ~0.1% of a diameter), so training targets are never clipped and
        inverse_postprocess stays the exact inverse on all training data; set wall_clamp false
        for the paper's unconstrained update. There is no lid, so nothing clips the top.
        """
        inset = WALL_CLAMP_DEPTH * radius
        x = torch.minimum(torch.maximum(position[:, 0], self.bounds[0, 0] + inset), self.bounds[0, 1] - inset)
        y = torch.maximum(position[:, 1], self.bounds[1, 0] + inset)
        return torch.stack([x, y], dim=1)

    # -- the two uses ----------------------------------------------------------------------------
    def predict_positions(self, position_sequence: torch.Tensor, context: Context) -> torch.Tensor:
        """Next position [N, 2] (m) from the last C positions [N, C, 2]."""
        position = self.postprocess(self(position_sequence, context), position_sequence)
        if self.config.wall_clamp:
            position = self.keep_inside_walls(position, context.radius)
        return position

    def predict_accelerations(
        self,
        next_position: torch.Tensor,
        position_sequence_noise: torch.Tensor,
        position_sequence: torch.Tensor,
        context: Context,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Training pair (predicted, target) normalised accelerations [N, 2] from next_position [N, 2],
        position_sequence [N, C, 2] and its noise position_sequence_noise [N, C, 2] (all m).

        The noise is added to the inputs; the target keeps the true next position relative to the
        noisy last position plus its own noise, so the model learns to correct the noisy velocity
        (Sanchez-Gonzalez et al. 2020).
        """
        noisy_sequence = position_sequence + position_sequence_noise
        predicted = self(noisy_sequence, context)
        target = self.inverse_postprocess(next_position + position_sequence_noise[:, -1], noisy_sequence)
        return predicted, target


# -- checkpoints ---------------------------------------------------------------------------------
MODEL_FORMAT = "gns-model-1"


def model_payload(simulator: LearnedSimulator) -> dict:
    return {
        "format": MODEL_FORMAT,
        "config": simulator.config.to_dict(),
        "state_dict": {k: v.detach().cpu() for k, v in simulator.state_dict().items()},
    }


def simulator_from_payload(payload: dict, where: str) -> LearnedSimulator:
    if not isinstance(payload, dict) or payload.get("format") != MODEL_FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise CheckpointError(f"{where}: not a GNS model checkpoint (format {found!r}, expected {MODEL_FORMAT!r})")
    try:
        config = SimulatorConfig.from_dict(payload["config"])
    except CheckpointError as exc:
        raise CheckpointError(f"{where}: {exc}") from None
    simulator = LearnedSimulator(config)
    try:
        simulator.load_state_dict(payload["state_dict"])
    except RuntimeError as exc:
        raise CheckpointError(f"{where}: weights do not fit the model its config describes: {exc}") from None
    return simulator


def load_simulator(
    path: str | os.PathLike, metadata: dict | None = None, device: torch.device | str | None = None
) -> LearnedSimulator:
    """The simulator saved at `path` (a model or training checkpoint), in eval mode; with
    `metadata` (a dataset's), also checks that the data fits it."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such checkpoint") from None
    except Exception as exc:  # noqa: BLE001 - torch raises many kinds for a corrupt file
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc})") from None
    if isinstance(payload, dict) and payload.get("format") == "gns-train-1":
        payload = payload["model"]  # a training checkpoint (gns.train) holds the model payload
    simulator = simulator_from_payload(payload, str(path))
    if metadata is not None:
        simulator.config.check_compatible(metadata, where=f"{path} with dataset {metadata.get('name', '?')}")
    return simulator.to(device or "cpu").eval()


def warm_start(simulator: LearnedSimulator, path: str | os.PathLike) -> dict:
    """Start `simulator` from the weights of the trained GNS at `path` (model or training checkpoint)
    of the same architecture, whose DEM parameters may be fewer (e.g. the base model's (mu, e)
    when this one adds a mechanism's parameter).

    Every weight of the same shape is copied. The first layers of the node and edge encoders are
    copied column block by column block (config.node_layout, config.edge_layout), the parameters
    block by parameter name; the columns of a parameter the other model lacks start at zero, so the
    warm-started GNS begins as the other one, blind to the new parameter, and training only has to
    learn what it changes. Buffers (the normalisation statistics, bounds, parameter ranges) stay
    this dataset's. Returns {"from": path, "new_parameters": [...], "copied": n tensors};
    CheckpointError when the architectures differ."""
    source = load_simulator(path)
    old, new = source.config, simulator.config
    missing = [k for k in old.parameter_names if k not in new.parameter_names]
    if missing:
        raise CheckpointError(f"warm start from {path}: it takes parameters {missing} this model lacks")
    old_weights = dict(source.named_parameters())
    # [hidden, features]: the only shapes that may differ, and the layouts of their columns
    first_layers = {
        "network.node_encoder.0.weight": (old.node_layout, new.node_layout),
        "network.edge_encoder.0.weight": (old.edge_layout, new.edge_layout),
    }
    copied = 0
    with torch.no_grad():
        for name, weight in simulator.named_parameters():
            other = old_weights.get(name)
            if name in first_layers and other is not None and other.shape[0] == weight.shape[0]:
                layouts = first_layers[name]
                weight.copy_(_feature_columns(other, old, new, layouts, weight.shape[1], path))
            elif other is None or other.shape != weight.shape:
                raise CheckpointError(
                    f"warm start from {path}: weight {name} is {None if other is None else tuple(other.shape)} "
                    f"there and {tuple(weight.shape)} here; warm start needs the same latent size and layers"
                )
            else:
                weight.copy_(other)
            copied += 1
    new_parameters = [k for k in new.parameter_names if k not in old.parameter_names]
    return {"from": str(path), "new_parameters": new_parameters, "copied": copied}


def _feature_columns(
    weight: torch.Tensor,
    old: SimulatorConfig,
    new: SimulatorConfig,
    layouts: tuple[list, list],
    width: int,
    path: str | os.PathLike,
) -> torch.Tensor:
    """An encoder's first-layer weight [hidden, F_old] laid out for `new`'s features [hidden,
    F_new]: blocks by name (layouts: old's and new's [(block, width)]), the parameters block by
    parameter name, a new parameter's column zero."""

    def columns(config: SimulatorConfig, layout: list) -> dict:
        out, start = {}, 0
        for block, size in layout:
            names = config.parameter_names if block == "parameters" else range(size)
            out.update({(block, k): start + j for j, k in enumerate(names)})
            start += size
        return out

    old_columns, new_columns = columns(old, layouts[0]), columns(new, layouts[1])
    result = torch.zeros(weight.shape[0], width, dtype=weight.dtype)
    for key, j in new_columns.items():
        if key in old_columns:
            result[:, j] = weight[:, old_columns[key]]
        elif key[0] != "parameters":
            raise CheckpointError(f"warm start from {path}: feature {key} has no counterpart there")
    return result
