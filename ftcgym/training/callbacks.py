"""Training callbacks: evaluation with the benchmark's metrics, and a plain tqdm progress bar (tqdm is a
dependency of ftcgym; SB3's own bar needs `rich` and counts the steps asked, not the whole rollouts run)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

from ftcgym.benchmark import metrics
from ftcgym.training.evaluate import DEFAULT_SCENARIO, score_policy


class BenchmarkEvalCallback(BaseCallback):
    """Every `eval_freq` env steps, fly the current model (deterministic, with the training VecNormalize's
    current statistics) through a benchmark scenario and log the benchmark's summary: `eval/success_rate`
    (share of episodes `recovered`), `eval/crash_rate`, `eval/recovery_latency_median`, `eval/altitude_loss`.
    Saves the best model so far (highest success rate, then lowest crash rate) to `best_dir` and appends
    each evaluation to `log_path` (JSON lines).

    Like SB3's EvalCallback, but scored with `ftcgym.benchmark` on the scenario's full episodes (the
    nominal controller before the alarm included) rather than on the training env's returns.
    """

    def __init__(self, eval_freq: int, scenario: str = DEFAULT_SCENARIO, episodes: int = 4, seed: int = 1000,
                 env_overrides: dict | None = None, env_id: str | None = None, task_kwargs: dict | None = None,
                 best_dir: str | Path | None = None, log_path: str | Path | None = None, verbose: int = 0):
        super().__init__(verbose)
        self.eval_freq, self.scenario, self.episodes, self.seed = int(eval_freq), scenario, int(episodes), seed
        self.env_overrides, self.env_id, self.task_kwargs = env_overrides or {}, env_id, task_kwargs
        self.best_dir = Path(best_dir) if best_dir else None
        self.log_path = Path(log_path) if log_path else None
        self.best_key = None
        self.last_summary: dict | None = None
        self._next = self.eval_freq

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next += self.eval_freq
            self.evaluate()
        return True

    def evaluate(self) -> dict:
        from ftcgym.training.policy import POLICY_CLASSES, LearnedPolicy, policy_name
        normalizer = self.model.get_vec_normalize_env()
        policy_class = POLICY_CLASSES.get(self.env_id, LearnedPolicy)   # the benchmark policy of the task
        rows = score_policy(lambda env: policy_class(self.model, normalizer, self.env_id, self.task_kwargs, env),
                            self.scenario, self.episodes, self.seed, self.env_overrides, policy_name(self.env_id))
        summary = metrics.summarize(rows)[0]
        losses = [row["altitude_loss"] for row in rows if row["altitude_loss"] is not None]
        summary = {**summary, "timesteps": self.num_timesteps,
                   "altitude_loss_mean": float(np.mean(losses)) if losses else None}
        for name in ("success_rate", "crash_rate", "recovery_latency_median", "altitude_loss_mean"):
            if summary[name] is not None:
                self.logger.record(f"eval/{name.replace('_mean', '')}", summary[name])
        if self.verbose:        # above a progress bar, if one is shown
            tqdm.write(f"eval at {self.num_timesteps} steps: success {summary['success_rate']:.2f}, "
                  f"crash {summary['crash_rate']:.2f} ({self.episodes} episodes of {self.scenario})")
        key = (summary["success_rate"] or 0.0, -(summary["crash_rate"] or 0.0))
        if self.best_dir is not None and (self.best_key is None or key > self.best_key):
            self.best_key = key
            self.best_dir.mkdir(parents=True, exist_ok=True)
            self.model.save(self.best_dir / "model.zip")
            if normalizer is not None:
                normalizer.save(str(self.best_dir / "vecnormalize.pkl"))
        if self.log_path is not None:
            with open(self.log_path, "a") as file:
                file.write(json.dumps(summary) + "\n")
        self.last_summary = summary
        return summary


class TqdmProgressCallback(BaseCallback):
    """A progress bar over the run's env steps with plain tqdm: `total` is the steps the run takes
    (`config.rl_steps`, whole rollouts), so the bar shows the share done and an ETA."""

    def __init__(self, total: int):
        super().__init__()
        self.total, self.bar = total, None

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.total, initial=self.num_timesteps, unit="step", desc="RL", dynamic_ncols=True)

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        self.close()

    def close(self) -> None:
        """Close the bar (also after an interrupted `learn`, which skips `_on_training_end`)."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None
