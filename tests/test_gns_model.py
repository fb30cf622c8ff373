"""GNS model: graph, features, network, output transform, differentiable checkpointed rollout, checkpoints."""

from __future__ import annotations

import platform
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch

from dem.trajectory import read_trajectory
from gns.data import TrajectoryWindows
from gns.dataset import read_metadata
from gns.graph import NeighbourCapWarning, radius_graph
from gns.network import EncodeProcessDecode
from gns.rollout import RolloutError, context_from_trajectory, rollout
from gns.settings import TrainSettings, simulator_config
from gns.simulator import CheckpointError, Context, LearnedSimulator, load_simulator, model_payload, warm_start
from gns.train import one_step_loss, pushforward_loss, random_walk_noise
from tests.gns_synthetic import synthetic_dataset

TINY = dict(latent_size=16, n_message_passing=2, connectivity_radius=4.0, noise_std=0.05)


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("gns_model"), n_train=2, n_frames=14)


@pytest.fixture(scope="module")
def metadata(dataset):
    return read_metadata(dataset)


def tiny_simulator(metadata, seed=0, **changes) -> LearnedSimulator:
    torch.manual_seed(seed)
    return LearnedSimulator(simulator_config(metadata, TrainSettings(**{**TINY, **changes})))


# -- graph -----------------------------------------------------------------------------------------
def test_radius_graph_matches_brute_force_and_keeps_graphs_apart():
    rng = np.random.default_rng(0)
    points = torch.tensor(rng.uniform(0, 1, (60, 2)))
    graph_index = torch.tensor(np.repeat([0, 1], 30))
    senders, receivers = radius_graph(points, 0.2, graph_index)
    distance = torch.cdist(points, points)
    same = graph_index[:, None] == graph_index[None, :]
    expected = {(i, j) for i, j in zip(*np.nonzero(((distance < 0.2) & same).numpy())) if i != j}
    assert set(zip(senders.tolist(), receivers.tolist())) == expected
    assert len(expected) > 60  # the check above compared a real graph


def test_neighbour_cap_warns_with_count_and_keeps_nearest():
    points = torch.tensor([[0.0, 0.0], [0.1, 0.0], [0.2, 0.0], [0.3, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        full = radius_graph(points, 1.0, max_neighbours=3)  # 3 neighbours each: nothing dropped
    assert full[0].numel() == 12
    with pytest.warns(NeighbourCapWarning, match="dropped 4 of 12 edges"):
        senders, receivers = radius_graph(points, 1.0, max_neighbours=2)
    kept = set(zip(senders.tolist(), receivers.tolist()))
    assert (1, 0) in kept and (2, 0) in kept and (3, 0) not in kept  # node 0 keeps its two nearest


# -- network ---------------------------------------------------------------------------------------
def test_processor_really_updates_edge_latents():
    torch.manual_seed(0)
    net = EncodeProcessDecode(node_in=5, edge_in=3, out_size=2, latent_size=16, mlp_hidden_size=16, n_message_passing=2)
    nodes, edges = net.encode(torch.randn(6, 5), torch.randn(8, 3))
    senders, receivers = torch.tensor([0, 1, 2, 3, 4, 5, 0, 2]), torch.tensor([1, 2, 3, 4, 5, 0, 3, 5])
    block = net.processor[0]
    _, edges_after_one = block(nodes, edges, senders, receivers)
    # the factorised first layer computes exactly the edge MLP on [e, v_s, v_r]
    direct = edges + block.edge_mlp(torch.cat([edges, nodes[senders], nodes[receivers]], dim=-1))
    assert torch.allclose(edges_after_one, direct, atol=1e-5)
    assert (edges_after_one - edges).abs().mean() > 1e-2
    # the second block sees the first block's updated edges: its output depends on them
    out = net.processor[1](*block(nodes, edges, senders, receivers), senders, receivers)
    out_stale = net.processor[1](block(nodes, edges, senders, receivers)[0], edges, senders, receivers)
    assert not torch.allclose(out[0], out_stale[0])


# -- simulator -------------------------------------------------------------------------------------
def test_output_transform_inverse_round_trips(metadata):
    sim = tiny_simulator(metadata).double()
    torch.manual_seed(1)
    sequence = torch.rand(10, 6, 2, dtype=torch.float64) * 0.05
    acceleration = torch.randn(10, 2, dtype=torch.float64)
    next_position = sim.postprocess(acceleration, sequence)
    assert torch.allclose(sim.inverse_postprocess(next_position, sequence), acceleration, atol=1e-10)
    # semi-implicit Euler: x' = x + (x - x_prev) + a (one frame)
    a_phys = acceleration * sim.acceleration_std + sim.acceleration_mean
    assert torch.allclose(next_position, 2 * sequence[:, -1] - sequence[:, -2] + a_phys)


def test_features_follow_layout_and_noise_widens_statistics(metadata, dataset):
    sim = tiny_simulator(metadata)
    c = sim.config
    assert [name for name, _ in c.node_layout] == ["velocity", "walls", "particle_type", "parameters", "layout", "size"]
    assert c.parameter_names == ["friction", "restitution"]
    noise = 0.05 * metadata["material_diameter"]
    assert np.allclose(sim.velocity_std.numpy(), np.hypot(metadata["velocity_std"], noise), rtol=1e-6)
    traj = read_trajectory(read_metadata(dataset)["splits"]["valid"][0])
    ctx = context_from_trajectory(sim, traj)
    sequence = torch.tensor(traj.positions[:6]).transpose(0, 1)
    nodes, edges, senders, receivers = sim.preprocess(sequence, ctx)
    assert nodes.shape == (traj.n_particles, sum(w for _, w in c.node_layout))
    assert [name for name, _ in c.edge_layout] == ["displacement", "distance", "gap", "parameters"]
    assert edges.shape == (len(senders), 6)
    gap = (edges[:, 2] - edges[:, 3]) * c.connectivity_radius_m  # centre distance - surface gap
    assert torch.allclose(gap, ctx.radius[senders] + ctx.radius[receivers])
    walls = nodes[:, 10:14]
    assert walls.min() >= -1 and walls.max() <= 1 and (walls == 1).any()  # far walls clip to 1
    params = nodes[:, 14 + c.type_embedding_size : 16 + c.type_embedding_size]
    low, high = metadata["parameter_ranges"]["friction"]
    assert torch.allclose(
        params[:, 0], torch.tensor((traj.attrs["friction"] - low) / (high - low), dtype=torch.float32)
    )
    # every edge carries its graph's scaled parameters, the same as its grains'
    torch.testing.assert_close(edges[:, 4:6], params[receivers])


def test_random_walk_noise_ends_with_requested_std():
    generator = torch.Generator().manual_seed(0)
    noise = random_walk_noise(torch.zeros(20000, 6, 2), 0.3, generator)
    assert torch.all(noise[:, 0] == 0)
    last_velocity_noise = noise[:, -1] - noise[:, -2]
    # the velocity noise is a random walk: its last step has variance 5 * (0.3^2 / 5)
    assert abs(float(last_velocity_noise.std()) - 0.3) < 0.01


def test_pushforward_loss_scores_the_models_own_state_against_the_true_frame(metadata, dataset):
    sim = tiny_simulator(metadata)
    c = sim.config
    paths = metadata["splits"]["train"]
    plain = TrajectoryWindows(paths, c.n_input_frames, c.parameter_names).batch([3])
    zero = torch.zeros_like(plain.position_sequence)
    assert torch.equal(pushforward_loss(sim, plain, 0), one_step_loss(sim, plain, zero))
    # p = 2: the window starting at the same frame, 2 frames longer; inputs are the model's own frames
    pushed = TrajectoryWindows(paths, c.n_input_frames + 2, c.parameter_names).batch([3])
    assert torch.equal(pushed.position_sequence[:, : c.n_input_frames], plain.position_sequence)
    sequence = pushed.position_sequence[:, : c.n_input_frames]
    with torch.no_grad():
        for _ in range(2):
            sequence = torch.cat([sequence[:, 1:], sim.predict_positions(sequence, pushed.context)[:, None]], dim=1)
    expected = torch.mean(
        torch.sum(
            (sim(sequence, pushed.context) - sim.inverse_postprocess(pushed.next_position, sequence)) ** 2, dim=-1
        )
    )
    loss = pushforward_loss(sim, pushed, 2)
    assert torch.allclose(loss, expected) and loss.requires_grad
    # the state the model reached differs from the true one, so this is not the one-step loss
    assert not torch.allclose(sequence[:, -1], pushed.position_sequence[:, -1])
    loss.backward()  # the gradient reaches the weights through the last step only
    assert all(p.grad is not None for p in sim.network.decoder.parameters())
    with pytest.raises(ValueError, match="pushforward_fraction"):
        TrainSettings(pushforward_fraction=1.5)


# -- rollout ---------------------------------------------------------------------------------------
def rollout_inputs(sim, dataset, dtype=torch.float64):
    traj = read_trajectory(read_metadata(dataset)["splits"]["valid"][0])
    ctx = context_from_trajectory(sim, traj, dtype=dtype)
    initial = torch.tensor(traj.positions[:6], dtype=dtype)
    return traj, ctx, initial


def test_rollout_gradient_wrt_parameters_matches_finite_differences(metadata, dataset):
    sim = tiny_simulator(metadata).double()
    _, ctx, initial = rollout_inputs(sim, dataset)
    ctx.parameters = ctx.parameters.clone().requires_grad_(True)
    initial = initial.clone().requires_grad_(True)

    def objective(parameters, initial_positions):
        ctx.parameters = parameters
        return rollout(sim, initial_positions, ctx, n_steps=4).positions[-1, :, 0].mean()

    value = objective(ctx.parameters, initial)
    grad_params, grad_initial = torch.autograd.grad(value, [ctx.parameters, initial])
    assert grad_params.abs().max() > 0 and grad_initial.abs().max() > 0
    eps = 1e-6
    parameters, initial = ctx.parameters.detach().clone(), initial.detach()
    with torch.no_grad():
        for k in range(2):  # friction, restitution
            step = torch.zeros_like(parameters)
            step[0, k] = eps
            fd = (objective(parameters + step, initial) - objective(parameters - step, initial)) / (2 * eps)
            assert float(fd) == pytest.approx(float(grad_params[0, k]), rel=1e-4, abs=1e-12)
        step = torch.zeros_like(initial)
        step[-1, 3, 1] = eps  # last input frame, grain 3, y
        fd = (objective(parameters, initial + step) - objective(parameters, initial - step)) / (2 * eps)
        assert float(fd) == pytest.approx(float(grad_initial[-1, 3, 1]), rel=1e-4, abs=1e-12)


def test_checkpointed_rollout_gradient_equals_plain(metadata, dataset):
    sim = tiny_simulator(metadata).double()
    _, ctx, initial = rollout_inputs(sim, dataset)
    grads = []
    for use_checkpoint in (False, True):
        ctx.parameters = ctx.parameters.detach().clone().requires_grad_(True)
        positions = rollout(sim, initial, ctx, n_steps=5, checkpoint=use_checkpoint).positions
        (positions[-1] ** 2).sum().backward()
        grads.append(ctx.parameters.grad.clone())
    assert grads[0].abs().max() > 0
    assert torch.allclose(grads[0], grads[1], rtol=1e-10, atol=0)


def test_checkpointing_keeps_saved_activations_from_growing_with_steps(metadata, dataset):
    """Bytes the autograd graph holds after a rollout of K steps: without checkpointing every
    step's activations stay; with it only each step's inputs."""
    sim = tiny_simulator(metadata).double()
    _, ctx, initial = rollout_inputs(sim, dataset)
    ctx.parameters = ctx.parameters.detach().clone().requires_grad_(True)

    def saved_bytes(n_steps, use_checkpoint):
        total = [0]

        def pack(tensor):
            total[0] += tensor.numel() * tensor.element_size()
            return tensor

        with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
            rollout(sim, initial, ctx, n_steps=n_steps, checkpoint=use_checkpoint)
        return total[0]

    per_step_plain = (saved_bytes(4, False) - saved_bytes(2, False)) / 2
    per_step_checkpointed = (saved_bytes(4, True) - saved_bytes(2, True)) / 2
    assert per_step_checkpointed < 0.2 * per_step_plain


def test_rollout_keeps_grains_out_of_walls_but_training_targets_are_not_clipped(metadata):
    sim = tiny_simulator(metadata).double()
    radius = torch.tensor([0.002, 0.002, 0.002], dtype=torch.float64)
    sunk = torch.tensor([[0.05, -0.003], [-0.001, 0.05], [0.05, 0.0015]], dtype=torch.float64)
    kept = sim.keep_inside_walls(sunk, radius)
    assert torch.allclose(kept, torch.tensor([[0.05, 0.001], [0.001, 0.05], [0.05, 0.0015]], dtype=torch.float64))
    # the training pair never passes through the clamp: a target below the floor stays below
    sequence = sunk[:, None, :].repeat(1, 6, 1)
    ctx = Context.single(
        torch.zeros(3),
        radius,
        torch.tensor([0.45, 0.6], dtype=torch.float64),
        torch.tensor([0.03, 0.04], dtype=torch.float64),
    )
    _, target = sim.predict_accelerations(sunk - 0.001, torch.zeros_like(sequence), sequence, ctx)
    assert torch.allclose(sim.postprocess(target, sequence), sunk - 0.001)


def test_rollout_that_leaves_the_box_raises_or_flags(metadata, dataset):
    sim = tiny_simulator(metadata)
    _, ctx, initial = rollout_inputs(sim, dataset, dtype=torch.float32)
    with torch.no_grad():
        sim.network.decoder[-1].bias.fill_(50.0)  # a huge constant acceleration throws grains out
    with pytest.raises(RolloutError, match="left the box"):
        rollout(sim, initial, ctx, n_steps=30)
    flagged = rollout(sim, initial, ctx, n_steps=30, on_invalid="flag")
    assert not flagged.valid and "left the box" in flagged.problem and flagged.positions.shape[0] < 36
    with torch.no_grad():
        sim.network.decoder[-1].bias.fill_(float("nan"))
    with pytest.raises(RolloutError, match="non-finite"):
        rollout(sim, initial, ctx, n_steps=3)


def test_rollout_refuses_parameters_outside_training_range(metadata, dataset):
    sim = tiny_simulator(metadata)
    _, ctx, initial = rollout_inputs(sim, dataset, dtype=torch.float32)
    ctx.parameters = torch.tensor([[5.0, 0.6]])
    with pytest.raises(ValueError, match="friction = 5 lies outside the range"):
        rollout(sim, initial, ctx, n_steps=1)


# -- checkpoints -----------------------------------------------------------------------------------
def test_checkpoint_round_trip_and_bad_checkpoints(metadata, tmp_path):
    sim = tiny_simulator(metadata)
    path = tmp_path / "model.pt"
    torch.save(model_payload(sim), path)
    loaded = load_simulator(path, metadata)
    assert all(torch.equal(a, b) for a, b in zip(sim.state_dict().values(), loaded.state_dict().values()))

    payload = model_payload(sim)
    payload["config"]["node_layout"][0] = ["velocity", 8]  # written by code with another layout
    torch.save(payload, tmp_path / "layout.pt")
    with pytest.raises(CheckpointError, match="feature layout mismatch"):
        load_simulator(tmp_path / "layout.pt")

    other = dict(metadata, parameter_ranges={**metadata["parameter_ranges"], "rolling_friction": [0.0, 0.1]})
    with pytest.raises(CheckpointError, match=r"parameter set \['friction', 'restitution', 'rolling_friction'\]"):
        load_simulator(path, other)

    payload = model_payload(tiny_simulator(metadata))
    payload["config"]["latent_size"] = 32  # weights of another size
    torch.save(payload, tmp_path / "shape.pt")
    with pytest.raises(CheckpointError, match="weights do not fit"):
        load_simulator(tmp_path / "shape.pt")

    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="junk.pt: not a readable checkpoint"):
        load_simulator(tmp_path / "junk.pt")


def test_warm_start_begins_as_the_base_gns_blind_to_the_new_parameter(metadata, dataset, tmp_path):
    """A GNS of an extended model (one more DEM parameter) warm-started from the base model's GNS
    predicts exactly what the base GNS does, whatever the new parameter's value; then training
    can move it (the new input's weights are zero, their gradient is not)."""
    base = tiny_simulator(metadata, seed=1)
    torch.save(model_payload(base), tmp_path / "base.pt")
    extended_ranges = {**metadata["parameter_ranges"], "bond_number": [0.0, 60.0]}
    extended = tiny_simulator(dict(metadata, parameter_ranges=extended_ranges), seed=2)
    assert extended.config.parameter_names == ["friction", "restitution", "bond_number"]
    info = warm_start(extended, tmp_path / "base.pt")
    assert info["new_parameters"] == ["bond_number"] and info["copied"] == len(list(extended.parameters()))
    _, ctx, initial = rollout_inputs(base, dataset, dtype=torch.float32)
    expected = base.predict_positions(initial.transpose(0, 1), ctx)
    outputs = []
    for bond in (0.0, 30.0, 60.0):
        bond_column = torch.full((ctx.parameters.shape[0], 1), bond)
        extended_ctx = Context(
            ctx.particle_type, ctx.radius, torch.cat([ctx.parameters, bond_column], 1), ctx.layout, ctx.graph_index
        )
        outputs.append(extended.predict_positions(initial.transpose(0, 1), extended_ctx))
        torch.testing.assert_close(outputs[-1], expected, rtol=0, atol=0)
    # the Bond number's input columns, on the nodes and on the edges, start at zero and can learn
    loss = extended.predict_positions(initial.transpose(0, 1), extended_ctx).square().sum()
    for first, layout in (
        (extended.network.node_encoder[0].weight, extended.config.node_layout),
        (extended.network.edge_encoder[0].weight, extended.config.edge_layout),
    ):
        column = [name for name, _ in layout].index("parameters")
        offset = sum(width for _, width in layout[:column]) + 2
        assert torch.all(first[:, offset] == 0)
        (gradient,) = torch.autograd.grad(loss, [first], retain_graph=True)
        assert gradient[:, offset].abs().max() > 0

    # a GNS whose parameters the source lacks cannot start a GNS without them
    torch.save(model_payload(extended), tmp_path / "extended.pt")
    with pytest.raises(CheckpointError, match=r"takes parameters \['bond_number'\] this model lacks"):
        warm_start(tiny_simulator(metadata), tmp_path / "extended.pt")
    with pytest.raises(CheckpointError, match="same latent size"):
        warm_start(
            tiny_simulator(dict(metadata, parameter_ranges=extended_ranges), latent_size=8), tmp_path / "base.pt"
        )


# -- memory ----------------------------------------------------------------------------------------
FAULTS_PER_FORWARD = r"""
import resource, sys, torch
torch.set_num_threads(1)
from gns.network import EncodeProcessDecode
if sys.argv[1] == "simulator":  # as every GNS process does: building a LearnedSimulator keeps freed memory
    from gns import memory
    from gns.simulator import LearnedSimulator
    from gns.settings import TrainSettings, simulator_config
    from gns.dataset import read_metadata
    LearnedSimulator(simulator_config(read_metadata(sys.argv[2]), TrainSettings()))
    assert memory.keep_freed_memory()
torch.manual_seed(0)
network = EncodeProcessDecode(20, 6, 2, 48, 48, 2, 3)
nodes, edges = torch.randn(1200, 20), torch.randn(12000, 6)
senders, receivers = torch.randint(0, 1200, (12000,)), torch.randint(0, 1200, (12000,))
with torch.no_grad():
    for _ in range(3):
        network(nodes, edges, senders, receivers)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        network(nodes, edges, senders, receivers)
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 5)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc's malloc")
def test_a_gns_process_does_not_fault_its_activations_in_anew_each_step(dataset):
    """A forward pass of the model's size (two 589-grain graphs: ~12,000 edges, 48 wide) allocates
    dozens of ~2 MB tensors; once a LearnedSimulator is built (gns.memory.keep_freed_memory), steps
    after the first reuse their freed memory instead of page-faulting it in again (~6,000 faults
    per forward without, on this project's machines). One process's count is one draw: on one 2-core
    Intel Xeon at rest, six processes each gave 4,548-9,942 without and 0-225 with, and one under a
    test run's load 472 against 8,060; so each side is the median of three processes."""

    def faults(mode: str) -> float:
        counts = []
        for _ in range(3):
            out = subprocess.run(
                [sys.executable, "-c", FAULTS_PER_FORWARD, mode, dataset], capture_output=True, text=True, check=True
            )
            counts.append(float(out.stdout.strip().splitlines()[-1]))
        return float(np.median(counts))

    plain, kept = faults("plain"), faults("simulator")
    assert kept <= max(50.0, plain / 20), f"{kept} page faults per forward with freed memory kept, {plain} without"
