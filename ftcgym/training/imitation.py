"""Imitation pre-training: DAgger on an expert that labels the task env's observations.

Learning the spin recovery from scratch is a hard exploration problem: a motor-level policy that does not
spin the vehicle up within a few hundred milliseconds of the alarm crashes, and random motor commands
almost never do. So the policy is first taught by DAgger (Ross, Gordon & Bagnell, "A reduction of imitation
learning and structured prediction to no-regret online learning", AISTATS 2011, Alg. 3.1), with the scripted
`ftc-spin` recovery as the expert (`RotorLossRecoveryEnv(expert=True)` puts its command in
`info["expert_action"]`), and then fine-tuned by the RL algorithm on the task's reward.

Per iteration i: fly the vectorised task env with the mixture pi_i = beta_i expert + (1 - beta_i) learner
(chosen per step; the learner's action plus Gaussian noise of `noise`, as DART, Laskey et al. CoRL 2017,
so the data covers the states the learner's errors lead to), add every (observation, expert action) pair
to the data set, update the observation normalisation with the new observations and fit the policy's mean
action to the expert's by mean squared error over the whole set. With `loss: saturated` a label at a bound
of the action space only penalises a mean short of that bound: the flown action is clipped, so any mean
beyond it flies the same, and the network may represent the expert's idle/full switching as a smooth
function crossing the bound instead of fitting a kink (a third of the spin recovery's labels sit at a
bound). With `loss: l1` the mean absolute error is minimised: where the features do not separate the
expert's idle and full commands, its minimiser is the labels' median (one of the two) rather than their mean,
which flies neither. With `final_epochs`, the whole data set is then fitted that many more passes with the
learning rate annealed to zero (cosine): the last iteration's fit has not converged (on the
rotor-loss-recovery config, 30 such passes took the action MSE from 0.0088 to 0.0055). The value head is then
fitted to the discounted returns of the last iteration's episodes (flown mostly by the learner), so the RL
fine-tuning does not start from an untrained critic.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EXPERT_KEY = "expert_action"
LOSSES = ("mse", "saturated", "l1")


@dataclass
class DaggerSettings:
    """The `pretrain` section of a task config (all optional)."""

    iterations: int = 6
    steps_per_iteration: int = 20_000     # env steps (all envs together) flown per iteration
    beta: float = 1.0                     # expert share in the first iteration ...
    beta_decay: float = 0.5               # ... multiplied by this each iteration
    noise: float = 0.1                    # std of the Gaussian noise on the learner's flown actions
    epochs: int = 8                       # passes over the data set per iteration
    batch_size: int = 256
    learning_rate: float = 1e-3
    log_std: float | None = -2.0          # the Gaussian policy's log std after pre-training (RL exploration)
    value_epochs: int = 10
    loss: str = "mse"                     # "mse"; "saturated": no penalty beyond a bound the label sits at; "l1"
    final_epochs: int = 0                 # after the last iteration: passes over the whole set, rate annealed to 0
    continue_from_init: bool = False      # with --init-from: DAgger continues from the saved model (else skipped)

    @classmethod
    def from_config(cls, section: dict) -> DaggerSettings:
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(section) - known - {"method"})
        if unknown:
            raise ValueError(f"pretrain: unknown keys {unknown}; accepted: {sorted(known)}")
        if section.get("method", "dagger") != "dagger":
            raise ValueError(f"pretrain.method: {section['method']!r}; accepted: ['dagger']")
        settings = cls(**{k: v for k, v in section.items() if k != "method"})
        if (settings.iterations < 1 or settings.steps_per_iteration < 1 or not 0 <= settings.beta <= 1
                or settings.final_epochs < 0):
            raise ValueError(f"pretrain: need iterations >= 1, steps_per_iteration >= 1, 0 <= beta <= 1, "
                             f"final_epochs >= 0; got {section}")
        if settings.loss not in LOSSES:
            raise ValueError(f"pretrain.loss: {settings.loss!r}; accepted: {list(LOSSES)}")
        return settings


def dagger(model, venv, settings: DaggerSettings, normalizer=None, seed: int = 0, log=print, progress=None,
           on_iteration=None) -> list[dict]:
    """Pre-train `model` (an SB3 actor-critic) by DAgger; returns one stats dict per iteration.

    `venv`: a VecEnv of the task whose envs put the expert's action in `info[EXPERT_KEY]` on reset and on
    every step. `normalizer`: the training run's VecNormalize, if any; its observation statistics are
    updated with the flown observations and the policy is fitted on normalised observations.
    `progress`: a tqdm-like bar (`update(n)` per env step of all envs, `set_description(text)`), or None.
    `on_iteration(stats)`: called after each iteration's fit (a checkpoint of the policy so far).
    """
    import torch

    low, high = model.action_space.low, model.action_space.high
    if settings.loss == "saturated" and not np.allclose(low, -high):
        raise ValueError(f"pretrain.loss 'saturated' needs a symmetric action space; got low {low}, high {high}")
    raw = venv
    rng = np.random.default_rng(seed)
    optimizer = torch.optim.Adam(model.policy.parameters(), lr=settings.learning_rate)
    observations, labels, history = [], [], []
    beta = settings.beta
    for iteration in range(settings.iterations):
        if progress is not None:
            progress.set_description(f"DAgger {iteration + 1}/{settings.iterations}")
        flown = _fly(model, raw, normalizer, beta, settings.noise, settings.steps_per_iteration, rng, progress)
        observations.append(flown["observations"])
        labels.append(flown["labels"])
        if normalizer is not None:
            normalizer.obs_rms.update(flown["observations"])
        if progress is not None:
            progress.set_description(f"DAgger {iteration + 1}/{settings.iterations} fit")
        fit = _fit_actor(model, optimizer, _normalized(normalizer, np.concatenate(observations)),
                         np.concatenate(labels), settings, rng)
        stats = {"iteration": iteration, "beta": beta, "samples": int(sum(len(o) for o in observations)),
                 **fit, "episodes": len(flown["returns"]),
                 "crash_rate": flown["crashes"] / max(len(flown["returns"]), 1),
                 "mean_return": float(np.mean(flown["returns"])) if flown["returns"] else None}
        history.append(stats)
        if on_iteration is not None:
            on_iteration(stats)
        log(f"dagger {iteration}: beta {beta:.3f}, {stats['samples']} samples, {fit_summary(fit)}, "
            f"{stats['episodes']} episodes flown, crash rate {stats['crash_rate']:.2f}")
        beta *= settings.beta_decay
    if progress is not None:
        progress.set_description("DAgger final fit")
    if settings.final_epochs:
        fit = _fit_actor(model, optimizer, _normalized(normalizer, np.concatenate(observations)),
                         np.concatenate(labels), settings, rng, epochs=settings.final_epochs, anneal=True)
        history[-1]["final_fit"] = {"epochs": settings.final_epochs, **fit}
        log(f"dagger final fit: {settings.final_epochs} epochs, learning rate annealed, {fit_summary(fit)}")
    _fit_value(model, optimizer, _normalized(normalizer, flown["value_observations"]), flown["value_targets"],
               settings, rng)
    if settings.log_std is not None and hasattr(model.policy, "log_std"):
        with torch.no_grad():
            model.policy.log_std.fill_(settings.log_std)
    return history


def _fly(model, venv, normalizer, beta: float, noise: float, steps: int, rng, progress=None) -> dict:
    """Fly the mixture policy for `steps` env steps; the expert's labels and the episodes' returns."""
    gamma = float(getattr(model, "gamma", 0.99))
    n = venv.num_envs
    obs = venv.reset()
    label = np.stack([info[EXPERT_KEY] for info in venv.reset_infos])
    observations, labels = [], []
    episode_obs, episode_rewards = [[] for _ in range(n)], [[] for _ in range(n)]
    value_obs, value_targets, returns, crashes = [], [], [], 0
    for _ in range(max(steps // n, 1)):
        observations.append(obs.copy())
        labels.append(label.copy())
        learner, _ = model.predict(_normalized(normalizer, obs), deterministic=True)
        learner = learner + noise * rng.standard_normal(learner.shape)
        use_expert = rng.random(n) < beta
        action = np.clip(np.where(use_expert[:, None], label, learner), -1.0, 1.0).astype(np.float32)
        next_obs, rewards, dones, infos = venv.step(action)
        if progress is not None:
            progress.update(n)
        label = np.stack([info[EXPERT_KEY] for info in infos])
        for i in range(n):
            episode_obs[i].append(obs[i])
            episode_rewards[i].append(rewards[i])
            if dones[i]:
                crashed = bool(infos[i].get("crashed"))
                crashes += crashed
                targets = _discounted(np.asarray(episode_rewards[i]), gamma, bootstrap=not crashed)
                value_obs.append(np.asarray(episode_obs[i]))
                value_targets.append(targets)
                returns.append(float(np.sum(episode_rewards[i])))
                episode_obs[i], episode_rewards[i] = [], []
                label[i] = venv.reset_infos[i][EXPERT_KEY]
        obs = next_obs
    empty = np.zeros((0, obs.shape[1]), np.float32)
    return {"observations": np.concatenate(observations), "labels": np.concatenate(labels),
            "value_observations": np.concatenate(value_obs) if value_obs else empty,
            "value_targets": np.concatenate(value_targets) if value_targets else np.zeros(0),
            "returns": returns, "crashes": crashes}


def _discounted(rewards: np.ndarray, gamma: float, bootstrap: bool) -> np.ndarray:
    """Discounted returns; a truncated (not crashed) episode continues as its last second's mean reward."""
    tail = float(np.mean(rewards[-min(len(rewards), 250):])) / (1.0 - gamma) if bootstrap else 0.0
    out, running = np.empty(len(rewards)), tail
    for t in range(len(rewards) - 1, -1, -1):
        running = rewards[t] + gamma * running
        out[t] = running
    return out


def _normalized(normalizer, observations: np.ndarray) -> np.ndarray:
    return normalizer.normalize_obs(observations) if normalizer is not None else observations


def _batches(size: int, batch_size: int, epochs: int, rng):
    for _ in range(epochs):
        order = rng.permutation(size)
        for start in range(0, size, batch_size):
            yield order[start:start + batch_size]


def _fit_actor(model, optimizer, observations, labels, settings: DaggerSettings, rng, epochs: int | None = None,
               anneal: bool = False) -> dict:
    """Fit the policy's mean action to the labels (`settings.loss`) for `epochs` (default `settings.epochs`),
    with `anneal` the learning rate cosine-annealed to 0 over them (then restored). Returns the last epoch's
    mean squared action error, `action_mse`, whatever the loss, so that runs with different losses compare;
    with another loss than "mse" also that loss's mean, `action_loss`."""
    import torch
    policy = model.policy
    epochs = settings.epochs if epochs is None else epochs
    obs_t = torch.as_tensor(observations, dtype=torch.float32)
    labels_t = torch.as_tensor(labels, dtype=torch.float32)
    bound = torch.as_tensor(model.action_space.high, dtype=torch.float32)
    policy.set_training_mode(True)
    losses, squared = [], []
    batches_per_epoch = -(-len(observations) // settings.batch_size)
    schedule = (torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=epochs * batches_per_epoch)
                if anneal else None)
    for batch in _batches(len(observations), settings.batch_size, epochs, rng):
        mean = _mean_action(policy, obs_t[batch])
        loss = _action_loss(mean, labels_t[batch], settings.loss, bound)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if schedule is not None:
            schedule.step()
        losses.append(float(loss.detach()))
        squared.append(float(torch.mean((mean.detach() - labels_t[batch]) ** 2)))
    policy.set_training_mode(False)
    for group in optimizer.param_groups:
        group["lr"] = settings.learning_rate
    fit = {"action_mse": float(np.mean(squared[-batches_per_epoch:]))}
    if settings.loss != "mse":
        fit["action_loss"] = float(np.mean(losses[-batches_per_epoch:]))
    return fit


def fit_summary(fit: dict) -> str:
    """A fit's errors as printed: the action MSE, and the fitted loss where it is another."""
    loss = f" ({fit['action_loss']:.4f} by the fitted loss)" if "action_loss" in fit else ""
    return f"action mse {fit['action_mse']:.4f}{loss}"


def _action_loss(mean, labels, kind: str, bound):
    """Mean squared error; "saturated": a label at +-bound (symmetric Box) leaves a mean beyond it unpenalised;
    "l1": mean absolute error."""
    import torch
    error = mean - labels
    if kind == "l1":
        return torch.mean(torch.abs(error))
    if kind == "saturated":
        error = torch.where(labels >= bound, torch.clamp(error, max=0.0), error)
        error = torch.where(labels <= -bound, torch.clamp(error, min=0.0), error)
    return torch.mean(error * error)


def _fit_value(model, optimizer, observations, targets, settings: DaggerSettings, rng) -> None:
    """Fit the value head to discounted returns (MSE)."""
    import torch
    if len(observations) == 0 or not hasattr(model.policy, "predict_values"):
        return
    obs_t = torch.as_tensor(observations, dtype=torch.float32)
    targets_t = torch.as_tensor(targets, dtype=torch.float32)
    model.policy.set_training_mode(True)
    for batch in _batches(len(observations), settings.batch_size, settings.value_epochs, rng):
        loss = torch.nn.functional.mse_loss(model.policy.predict_values(obs_t[batch]).flatten(), targets_t[batch])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.policy.set_training_mode(False)


def _mean_action(policy, observations):
    """The Gaussian policy's mean action (SB3 ActorCriticPolicy) for a batch of normalised observations."""
    features = policy.extract_features(observations, policy.pi_features_extractor)
    latent_pi = policy.mlp_extractor.forward_actor(features)
    return policy.action_net(latent_pi)
