"""Training: one-step acceleration loss with random-walk input noise, Adam with exponential decay.

A fraction `pushforward_fraction` of the steps (default 0.5) use the pushforward loss instead
(Brandstetter, Worrall & Welling 2022): the model first rolls the window `pushforward_steps` of its
own steps forward without gradient, and the loss asks it to land on the true next frame from
there. The random-walk noise of Sanchez-Gonzalez et al. stands in for rollout error, but at this
frame interval (grains move up to 2.5 diameters a frame, and a one-step prediction errs by about
0.1 diameter a step) it is a hundred times smaller than the error a rollout makes; trained on its
own drifted states the model learns to correct them. On quartz_multiple it cut the validation
runout MSE at equal steps by several times (docs/experiments/gns-training.md).

Outputs in `out_dir`:
  checkpoint_last.pt  model, optimiser, sampler and noise RNG states, step, metrics history:
                      a killed training started again with the same settings resumes from it and
                      continues exactly as if never stopped (same samples, same noise, same loss);
                      one that cannot be read (truncated) is moved aside and training starts clean
  model_best.pt       the validated model (the exponential moving average of the weights,
                      ema_decay) with the lowest validation runout MSE so far (the paper keeps
                      the best validated model; it validated every 500 steps)
  metrics.csv, loss_curve.png  the rows logged and validated so far, and their figure (gns/train_metrics.py)
Validation, every `validate_every` steps: the one-step loss on fixed windows of the valid split
and a full rollout of every valid trajectory, scored by the runout MSE against its DEM curve.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import os
import time
from pathlib import Path

import numpy as np
import torch

from dem.atomic import atomic_path
from dem.progress import progress_logger
from dem.runout import RunoutError, RunoutMethod
from dem.trajectory import read_trajectory
from gns.data import Batch, TrajectoryWindows
from gns.dataset import read_metadata, split_paths, with_off_values
from gns.graph import graph_summary, radius_graph
from gns.settings import TrainSettings, simulator_config
from gns.simulator import CheckpointError, LearnedSimulator, SimulatorConfig, model_payload, warm_start
from gns.train_metrics import METRICS_COLUMNS, write_metrics

log = logging.getLogger(__name__)


class UnreadableCheckpoint(CheckpointError):
    """checkpoint_last.pt cannot be read (truncated, damaged): refused, and training starts clean."""


TRAIN_FORMAT = "gns-train-1"
# settings that may change when a training resumes; every other one shapes the result
RESUMABLE = ("steps", "log_every", "checkpoint_every", "device")


def random_walk_noise(position_sequence: torch.Tensor, noise_std_m: float, generator: torch.Generator) -> torch.Tensor:
    """Noise [N, C, 2] (m) for position_sequence [N, C, 2]: a random walk on the C - 1 velocities
    whose last step has std noise_std_m (m/frame); the first position is left untouched."""
    n, c, _ = position_sequence.shape
    velocity_noise = torch.randn((n, c - 1, 2), generator=generator) * (noise_std_m / math.sqrt(c - 1))
    position_noise = torch.cumsum(torch.cumsum(velocity_noise, dim=1), dim=1)
    return torch.cat([torch.zeros((n, 1, 2)), position_noise], dim=1)


def one_step_loss(simulator: LearnedSimulator, batch: Batch, noise: torch.Tensor) -> torch.Tensor:
    """Mean over particles of the squared error in normalised acceleration (summed over x, y); noise
    [N, C, 2] (m) is added to batch.position_sequence (see random_walk_noise)."""
    predicted, target = simulator.predict_accelerations(
        batch.next_position, noise, batch.position_sequence, batch.context
    )
    return torch.mean(torch.sum((predicted - target) ** 2, dim=-1))


def pushforward_loss(simulator: LearnedSimulator, batch: Batch, pushforward_steps: int) -> torch.Tensor:
    """One-step loss from the model's own state: batch.position_sequence [N, C + p, 2] holds the
    true frames; the model rolls its first C frames p steps forward without gradient (as in a
    rollout, walls included), then predicts the next frame from there, scored against the true
    batch.next_position as a normalised acceleration (same units as one_step_loss). p = 0 is
    one_step_loss without noise."""
    c = simulator.config.n_input_frames
    sequence = batch.position_sequence[:, :c]
    with torch.no_grad():
        for _ in range(pushforward_steps):
            predicted = simulator.predict_positions(sequence, batch.context)
            sequence = torch.cat([sequence[:, 1:], predicted[:, None]], dim=1)
    pushed = Batch(sequence, batch.next_position, batch.context)
    return one_step_loss(simulator, pushed, torch.zeros_like(sequence))


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


class Trainer:
    """State of one training run; `run()` trains to settings.steps, resuming when it can."""

    def __init__(
        self,
        metadata_path: str | os.PathLike,
        out_dir: str | os.PathLike,
        settings: TrainSettings,
        runout: RunoutMethod | None = None,
    ):
        self.metadata_path = str(metadata_path)
        self.runout = RunoutMethod.from_config(runout)  # how the validation runout MSE reads L*
        self.metadata = read_metadata(metadata_path)
        self.out_dir = Path(out_dir)
        self.settings = settings
        self.device = resolve_device(settings.device)
        self.config = simulator_config(self.metadata, settings)
        names = self.config.parameter_names
        self.off = self.metadata.get("parameter_off")  # what a base model's run leaves out
        self.train_windows = TrajectoryWindows(
            split_paths(self.metadata, "train"), settings.n_input_frames, names, self.config.dt_frame, self.off
        )
        # pushforward steps need p more frames before the target
        self.pushforward_windows = (
            TrajectoryWindows(
                split_paths(self.metadata, "train"),
                settings.n_input_frames + settings.pushforward_steps,
                names,
                self.config.dt_frame,
                self.off,
            )
            if settings.pushforward_steps
            else None
        )
        valid_paths = split_paths(self.metadata, "valid")
        picked = np.linspace(0, len(valid_paths) - 1, min(settings.validation_rollouts, len(valid_paths)))
        self.valid_paths = [valid_paths[k] for k in sorted(set(picked.round().astype(int)))]
        self.valid_windows = TrajectoryWindows(
            valid_paths, settings.n_input_frames, names, self.config.dt_frame, self.off
        )
        n_valid = min(settings.validation_windows, len(self.valid_windows))
        self.valid_indices = np.linspace(0, len(self.valid_windows) - 1, n_valid).round().astype(int)
        torch.manual_seed(settings.seed)
        self.simulator = LearnedSimulator(self.config).to(self.device)
        self.warm_started = warm_start(self.simulator, settings.init_from) if settings.init_from else None
        if self.warm_started:
            log.info("warm start: %s", self.warm_started)
        # foreach: one kernel per operation over every weight tensor instead of a loop over them
        # (torch picks it by itself only on CUDA); the same update
        self.optimizer = torch.optim.Adam(self.simulator.parameters(), lr=settings.learning_rate, foreach=True)
        self.averaged = copy.deepcopy(self.simulator)  # the EMA of the weights (ema_decay)
        self.sampler = np.random.default_rng(settings.seed)
        self.noise = torch.Generator().manual_seed(settings.seed)
        self.step = 0
        self.best = {"step": None, "valid_runout_mse": math.inf}
        self.best_payload = None  # model_best.pt's content, kept in the checkpoint too
        self.history: list[dict] = []
        self.accumulated = self.empty_accumulator()
        self.resumed_from = None

    # -- checkpoints -------------------------------------------------------------------------------
    @property
    def checkpoint_path(self) -> Path:
        return self.out_dir / "checkpoint_last.pt"

    def save_checkpoint(self) -> None:
        payload = {
            "format": TRAIN_FORMAT,
            "model": model_payload(self.simulator),
            "averaged_model": model_payload(self.averaged),
            "optimizer": self.optimizer.state_dict(),
            "step": self.step,
            "settings": self.saved_settings(),
            "dataset": self.metadata.get("name"),
            "sampler_state": self.sampler.bit_generator.state,
            "noise_state": self.noise.get_state(),
            "best": self.best,
            "best_model": self.best_payload,
            "history": self.history,
            "accumulated": self.accumulated,
        }
        with atomic_path(self.checkpoint_path) as tmp:
            torch.save(payload, tmp)

    def resume(self) -> bool:
        """Load checkpoint_last.pt when present; CheckpointError when it does not fit these settings,
        UnreadableCheckpoint when it cannot be read (truncated)."""
        path = self.checkpoint_path
        if not path.exists():
            return False
        try:
            payload = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as exc:  # noqa: BLE001  (torch raises several kinds on a damaged file)
            raise UnreadableCheckpoint(f"{path}: not a readable training checkpoint, truncated? ({exc})") from None
        if not isinstance(payload, dict) or payload.get("format") != TRAIN_FORMAT:
            raise CheckpointError(f"{path}: not a GNS training checkpoint; delete it to start afresh")
        saved_settings = payload["settings"]  # a key the checkpoint lacks counts as changed
        changed = {
            k: (saved_settings.get(k, "absent"), v)
            for k, v in self.saved_settings().items()
            if k not in RESUMABLE and saved_settings.get(k, "absent") != v
        }
        if changed:
            raise CheckpointError(
                f"{path}: was trained with other settings {changed} (checkpoint, now); "
                "restore them or delete the output folder to start afresh"
            )
        saved = SimulatorConfig.from_dict(payload["model"]["config"])
        saved.check_compatible(self.metadata, where=f"{path} resumed on dataset {self.metadata.get('name', '?')}")
        if saved.to_dict() != self.config.to_dict():
            diff = {k: v for k, v in saved.to_dict().items() if self.config.to_dict().get(k) != v}
            raise CheckpointError(
                f"{path}: model config differs from this dataset's ({sorted(diff)}); "
                "delete the output folder to start afresh"
            )
        if payload.get("best_model") is None and payload["best"]["step"] is not None:
            # older than the kept best model: a lost model_best.pt could not be written again
            raise CheckpointError(
                f"{path}: holds no copy of the best model (an older checkpoint); delete it to start afresh"
            )
        # every check above comes before any state is loaded: a refused checkpoint leaves a fresh trainer
        self.simulator.load_state_dict(payload["model"]["state_dict"])
        self.averaged.load_state_dict(payload["averaged_model"]["state_dict"])
        self.optimizer.load_state_dict(payload["optimizer"])
        self.sampler.bit_generator.state = payload["sampler_state"]
        self.noise.set_state(payload["noise_state"])
        self.step, self.best, self.history = payload["step"], payload["best"], payload["history"]
        self.best_payload = payload["best_model"]
        self.accumulated = payload["accumulated"]
        self.resumed_from = self.step
        log.info("resumed %s at step %d", path, self.step)
        return True

    def set_aside(self, reason: CheckpointError, suffix: str) -> None:
        """Move a refused checkpoint_last.pt to checkpoint_last<suffix> (kept, not deleted) and say
        that training starts clean; the trainer is still fresh (resume loads nothing it refuses)."""
        aside = self.checkpoint_path.with_suffix(suffix)
        self.checkpoint_path.replace(aside)
        log.warning("%s; moved to %s, training starts clean from step 0", reason, aside)

    def saved_settings(self) -> dict:
        """What a checkpoint must match to be resumed: the settings and the validation's runout method."""
        return dict(dataclasses.asdict(self.settings), runout=self.runout.to_config())

    # -- one step ---------------------------------------------------------------------------------
    def train_step(self) -> float:
        s = self.settings
        for group in self.optimizer.param_groups:
            group["lr"] = s.learning_rate_at(self.step)
        self.simulator.train()
        pushforward = self.pushforward_windows is not None and self.sampler.random() < s.pushforward_fraction
        if pushforward:
            indices = self.sampler.integers(0, len(self.pushforward_windows), s.batch_size)
            batch = self.pushforward_windows.batch(indices).to(self.device)
            loss = pushforward_loss(self.simulator, batch, s.pushforward_steps)
        else:
            indices = self.sampler.integers(0, len(self.train_windows), s.batch_size)
            batch = self.train_windows.batch(indices)
            noise = random_walk_noise(batch.position_sequence, self.config.noise_std_m, self.noise)
            batch = batch.to(self.device)
            loss = one_step_loss(self.simulator, batch, noise.to(self.device))
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        with torch.no_grad():
            decay = s.ema_decay
            averaged = list(self.averaged.parameters())
            torch._foreach_mul_(averaged, decay)
            torch._foreach_add_(averaged, list(self.simulator.parameters()), alpha=1.0 - decay)
        self.step += 1
        value = float(loss.detach())
        if not math.isfinite(value):
            raise FloatingPointError(f"training loss turned {value} at step {self.step}; lower learning_rate")
        self.last_batch = batch
        kind = "pushforward_" if pushforward else ""  # the two losses are logged apart
        self.accumulated[kind + "loss"] += value
        self.accumulated[kind + "count"] += 1
        return value

    @staticmethod
    def empty_accumulator() -> dict:
        """Sums of the one-step and the pushforward losses since the last log row."""
        return {"loss": 0.0, "count": 0, "pushforward_loss": 0.0, "pushforward_count": 0}

    # -- validation --------------------------------------------------------------------------------
    def validate(self) -> dict:
        from gns.evaluate import rollout_runout_mse
        from gns.rollout import rollout_trajectory

        model = self.averaged
        model.eval()
        losses, position_errors = [], []
        with torch.no_grad():
            for k in self.valid_indices:
                batch = self.valid_windows.batch([k]).to(self.device)
                zero = torch.zeros_like(batch.position_sequence)
                losses.append(float(one_step_loss(model, batch, zero)))
                predicted = model.predict_positions(batch.position_sequence, batch.context)
                position_errors.append(float(torch.mean(torch.sum((predicted - batch.next_position) ** 2, -1))))
        runout_errors, failed = [], 0
        for path in self.valid_paths:
            dem = read_trajectory(path)
            dem.attrs = with_off_values(dem.attrs, self.off)
            gns = rollout_trajectory(model, dem, on_invalid="flag")
            if not gns.attrs["rollout_valid"]:
                failed += 1
                log.warning("validation rollout of %s failed: %s", path, gns.attrs["rollout_problem"])
                runout_errors.append(math.inf)
            else:
                try:
                    runout_errors.append(rollout_runout_mse(dem, gns, self.runout))
                except RunoutError as exc:  # spread too thin for the runout rule: a failed rollout
                    failed += 1
                    log.warning("validation rollout of %s has no runout: %s", path, exc)
                    runout_errors.append(math.inf)
        return {
            "valid_one_step_loss": float(np.mean(losses)),
            "valid_position_mse": float(np.mean(position_errors)),
            "valid_runout_mse": float(np.mean(runout_errors)),
            "valid_rollouts_failed": failed,
        }

    # -- the loop ---------------------------------------------------------------------------------
    def run(self, resume: bool = True, restart_on_mismatch: bool = False) -> dict:
        s = self.settings
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if resume:
            try:
                self.resume()
            except UnreadableCheckpoint as exc:  # truncated: nothing in it can be resumed
                self.set_aside(exc, ".unreadable.pt")
            except CheckpointError as exc:  # made for other data or settings
                if not restart_on_mismatch:
                    raise
                self.set_aside(exc, ".stale.pt")
        elif self.checkpoint_path.exists():
            raise CheckpointError(f"{self.checkpoint_path} exists and resume=False; delete it to start afresh")
        log.info(
            "training %s on %s: %d train windows from %d files, %d valid trajectories, device %s, "
            "connectivity radius %.3g m",
            self.out_dir,
            self.metadata.get("name"),
            len(self.train_windows),
            len(self.train_windows.files),
            len(self.valid_paths),
            self.device,
            self.config.connectivity_radius_m,
        )
        tick, tick_step = time.perf_counter(), self.step
        progress = progress_logger(f"training {self.metadata.get('name')}, {s.steps} steps", log)
        while self.step < s.steps:
            loss = self.train_step()
            self.last_loss = loss
            progress(self.step / s.steps)
            row = None
            if self.step % s.log_every == 0 or self.step == s.steps:
                now = time.perf_counter()
                row = self.log_row(self.step - tick_step, now - tick)
                tick, tick_step = now, self.step
            if self.step % s.validate_every == 0 or self.step == s.steps:
                metrics = self.validate()
                row = row or self.log_row(0, 0.0)
                row.update(metrics)
                log.info(
                    "step %d validation: one-step loss %.4g, runout MSE %.4g (%d rollouts failed)",
                    self.step,
                    metrics["valid_one_step_loss"],
                    metrics["valid_runout_mse"],
                    metrics["valid_rollouts_failed"],
                )
                if metrics["valid_runout_mse"] < self.best["valid_runout_mse"]:
                    self.best = {"step": self.step, "valid_runout_mse": metrics["valid_runout_mse"]}
                    self.save_best()
            if row is not None:
                self.history.append(row)
            validated = self.step % s.validate_every == 0 or self.step == s.steps
            if validated or self.step % s.checkpoint_every == 0:
                self.save_checkpoint()
                write_metrics(self.history, self.out_dir, self.best, figure=validated)
        if self.best["step"] is None:  # every validation rollout failed: keep the last model, say so
            log.warning("no validation rollout succeeded; model_best.pt holds the last model")
            self.save_best()
        # a finished run resumed (e.g. Snakemake reran the job and removed its outputs) writes them again
        self.write_best()
        write_metrics(self.history, self.out_dir, self.best)
        return {
            "step": self.step,
            "resumed_from": self.resumed_from,
            "warm_start": self.warm_started,
            "best": self.best,
            "last_train_loss": self.history[-1]["train_loss"] if self.history else None,
            "out_dir": str(self.out_dir),
        }

    def log_row(self, steps: int, seconds: float) -> dict:
        acc = self.accumulated
        mean = lambda kind: acc[kind + "loss"] / acc[kind + "count"] if acc[kind + "count"] else math.nan  # noqa: E731
        row = {key: math.nan for key in METRICS_COLUMNS}
        row.update(
            step=self.step,
            learning_rate=self.settings.learning_rate_at(self.step),
            train_loss=mean(""),
            train_pushforward_loss=mean("pushforward_"),
            steps_per_s=steps / seconds if seconds > 0 else math.nan,
        )
        batch = getattr(self, "last_batch", None)
        if batch is not None:  # the graph of the last training batch, per graph
            senders, _ = radius_graph(
                batch.position_sequence[:, -1],
                self.config.connectivity_radius_m,
                batch.context.graph_index,
                self.config.max_neighbours,
            )
            graphs = int(batch.context.graph_index.max()) + 1
            graph = graph_summary(batch.position_sequence.shape[0], senders)
            row.update(edges_per_node=graph["edges_per_node"], particles_per_graph=graph["particles"] / graphs)
        if steps:
            log.info(
                "step %d/%d loss %.4g pushforward loss %.4g lr %.3g %.2f steps/s, %d particles/graph, %.1f edges/node",
                self.step,
                self.settings.steps,
                row["train_loss"],
                row["train_pushforward_loss"],
                row["learning_rate"],
                row["steps_per_s"],
                row["particles_per_graph"],
                row["edges_per_node"],
            )
        self.accumulated = self.empty_accumulator()
        return row

    # -- outputs -----------------------------------------------------------------------------------
    def save_best(self) -> None:
        """The current averaged model becomes the best one: model_best.pt, and kept for the checkpoint."""
        self.best_payload = model_payload(self.averaged)
        # cloned: on the CPU the payload's tensors share memory with the model the EMA keeps updating
        self.best_payload["state_dict"] = {k: v.clone() for k, v in self.best_payload["state_dict"].items()}
        self.best_payload.update(
            step=self.step,
            valid_runout_mse=self.best["valid_runout_mse"],
            dataset=self.metadata.get("name"),
            settings=dataclasses.asdict(self.settings),
        )
        self.write_best()

    def write_best(self) -> None:
        if self.best_payload is None:
            raise CheckpointError(f"{self.out_dir}: no best model to write (no validation has run)")
        self.out_dir.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.out_dir / "model_best.pt") as tmp:
            torch.save(self.best_payload, tmp)


def train(
    metadata_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    settings: TrainSettings | dict | None = None,
    resume: bool = True,
    restart_on_mismatch: bool = False,
    runout: RunoutMethod | dict | None = None,
) -> dict:
    """Train (or resume training) a GNS on the dataset at `metadata_path`; outputs in `out_dir`.

    resume: continue from out_dir/checkpoint_last.pt when present. A checkpoint made with other
    settings or data raises CheckpointError, or with restart_on_mismatch is moved aside and
    training starts afresh (the workflow's choice: changed inputs mean a new model). A checkpoint
    that cannot be read (truncated) is always moved aside (checkpoint_last.unreadable.pt) with a
    warning, and training starts clean. runout: how the validation runout MSE (which picks the
    saved model) reads L* (dem.runout; None: its default).
    """
    if not isinstance(settings, TrainSettings):
        settings = TrainSettings.from_config(settings)
    return Trainer(metadata_path, out_dir, settings, runout).run(resume=resume, restart_on_mismatch=restart_on_mismatch)
