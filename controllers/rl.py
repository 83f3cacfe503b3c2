"""Training, saving and loading stable-baselines3 policies for the spherical robot.

A trained policy is three files with one stem, e.g. ``logs/ppo/SphereBotWaypoints-v1_1/ppo-waypoints-ekf``:

- ``<stem>.zip``: the SB3 model (the best one found by the evaluation callback);
- ``<stem>.vecnormalize.npz``: the ``VecNormalize`` statistics it was trained with, as plain arrays;
- ``<stem>.json``: the exact command, algorithm, task, estimator, environment arguments,
  timesteps, seed, wall time, training throughput, the observation names and the final
  evaluation.

``load_policy(name_or_path)`` returns a ``PolicyController`` (the ``Controller`` interface):
a name of ``available_policies()`` (shipped in the package, found from any folder) or a path.
Nothing is unpickled: ``controllers.policy_io`` reads the zip with its pickled entries refused.
Checkpoints and the best model are written atomically (``policy_io.atomic_write``).
Hyperparameters live in rl-zoo3-style YAML files, ``controllers/hyperparams/<algo>.yml``,
keyed by environment id. Heavy imports (torch, SB3) happen inside the functions, so that
``import controllers`` stays light.
"""
from __future__ import annotations

import copy
import json
import os
import sys
import time
import warnings
from importlib import resources
from pathlib import Path
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from controllers.base import Controller, obs_batch
from fusion.checks import choice, flag, integer, require_import
from controllers.policy_io import (PolicyError, atomic_write, drop_optimizer_state, load_model, load_normalization,
                                   load_replay, save_model, save_normalization, save_replay, vec_normalize,
                                   write_text)

__all__ = ["ALGOS", "TASK_IDS", "POLICY_DIR", "hyperparams", "train", "load_policy", "PolicyController",
           "policy_stem", "PolicyError", "available_policies", "install_policy", "UntrustedPolicyWarning"]

ALGOS = ("ppo", "sac")
TASK_IDS = {"track": "SphereBotTrack-v1", "waypoints": "SphereBotWaypoints-v1"}
# package resources (not the current folder): found the same from a checkout or a wheel
HYPERPARAMS_DIR = Path(str(resources.files("controllers") / "hyperparams"))
POLICY_DIR = Path(str(resources.files("controllers") / "policies"))
NORM_SUFFIX = ".vecnormalize.npz"
#: how the training environments run: one process each (subproc), all in this process one
#: after another (single), or all in one process and one physics client (batched, envs/vector.py)
VEC_ENVS = ("single", "subproc", "batched")


class UntrustedPolicyWarning(UserWarning):
    """A policy loaded from outside the package."""


def available_policies() -> list[str]:
    """The names of the policies shipped in the package (``load_policy(name)`` takes them)."""
    return sorted(p.stem for p in POLICY_DIR.glob("*.zip"))


def policy_stem(algo: str, task: str, estimator: str, directory: str | os.PathLike = POLICY_DIR,
                seed: int = 0) -> Path:
    """The policy of (algo, task, estimator) in ``directory`` (default: the package's): of
    training seed 0 ``<algo>-<task>-<estimator>`` (the one the comparison runs), of other
    seeds ``<algo>-<task>-<estimator>-seed<seed>``."""
    return Path(directory) / (f"{algo}-{task}-{estimator}" + (f"-seed{seed}" if seed else ""))


FINAL_EVAL_SEED = 1_000_000     # the final evaluation's episodes: seeds neither training nor the comparison use


def final_evaluation(stem, task, estimator, env_kwargs=None, episodes=10, seed=FINAL_EVAL_SEED) -> dict:
    """Evaluate the policy ``stem`` (``controllers.evaluate``, ``episodes`` from ``seed``) and
    write the means into its JSON as ``final_evaluation``; returns them."""
    from controllers.evaluation import evaluate
    ctrl = load_policy(stem, trusted=True)      # written by this run
    res = evaluate(ctrl, dict(env_kwargs or {}, task=task, estimator=estimator), episodes=episodes, seed=seed)
    summary = {k: v["mean"] for k, v in res["summary"].items()}
    meta_path = Path(str(stem) + ".json")
    meta = json.loads(meta_path.read_text())
    meta["final_evaluation"] = {"episodes": episodes, "seed": seed, "mean": summary}
    atomic_write(meta_path, lambda f: f.write(json.dumps(meta, indent=2).encode()))
    return summary


def estimator_config(estimator: str, env_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """The estimator's parameters in an environment made with ``env_kwargs``: its defaults at
    the environment's IMU rate with the env's ``estimator_params`` over them ({} for truth).
    A policy's JSON records them, so that a comparison can tell a policy trained with other
    estimator defaults (controllers.compare.plan warns)."""
    if estimator == "truth":
        return {}
    import inspect

    import fusion
    from envs.base import SphereRobotBase
    kw = dict(env_kwargs or {})
    imu_hz = kw.get("imu_hz", inspect.signature(SphereRobotBase.__init__).parameters["imu_hz"].default)
    return fusion.make(estimator, float(imu_hz), **dict(kw.get("estimator_params") or {})).params


def new_run_stem(algo: str, task: str, estimator: str, log_folder: str | os.PathLike = "logs") -> Path:
    """rl-zoo3's layout: ``<log_folder>/<algo>/<env-id>_<n>/<algo>-<task>-<estimator>``, ``n`` one
    more than the highest run there (from 1)."""
    base = Path(log_folder) / algo
    env_id = TASK_IDS[task]
    runs = [int(p.name.rsplit("_", 1)[1]) for p in base.glob(f"{env_id}_*") if p.name.rsplit("_", 1)[1].isdigit()]
    return base / f"{env_id}_{max(runs, default=0) + 1}" / f"{algo}-{task}-{estimator}"


def latest_run_stem(algo: str, task: str, estimator: str, log_folder: str | os.PathLike = "logs") -> Path | None:
    """The newest run of (algo, task, estimator) in ``log_folder`` that holds checkpoints, or None."""
    base = Path(log_folder) / algo
    env_id = TASK_IDS[task]
    runs = sorted((int(p.name.rsplit("_", 1)[1]), p) for p in base.glob(f"{env_id}_*")
                  if p.name.rsplit("_", 1)[1].isdigit())
    for _, run in reversed(runs):
        stem = run / f"{algo}-{task}-{estimator}"
        if _checkpoints(Path(str(stem) + ".run") / "checkpoints"):
            return stem
    return None


def hyperparams(algo: str, task: str) -> dict[str, Any]:
    """The YAML entry of ``algo`` for ``task``'s environment id, as a dict (a copy)."""
    import yaml
    choice("algorithm", algo, ALGOS)
    choice("task", task, tuple(TASK_IDS))
    path = HYPERPARAMS_DIR / f"{algo}.yml"
    with open(path) as f:
        table = yaml.safe_load(f)
    env_id = TASK_IDS[task]
    if env_id not in table:
        raise ValueError(f"{path} has no entry for {env_id}")
    return dict(table[env_id])


def _monitor_file(monitor_dir, rank, append):
    """The Monitor file name for ``rank``; when appending (a resumed run), an unfinished last
    line (the run was killed mid-write) is cut so that the next row starts on its own line."""
    if monitor_dir is None:
        return None
    base = os.path.join(monitor_dir, str(rank))
    path = base + ".monitor.csv"
    if append and os.path.isfile(path):
        with open(path, "rb+") as f:
            text = f.read()
            if text and not text.endswith(b"\n"):
                f.truncate(text.rfind(b"\n") + 1)
    return base


def _make_env_fn(task, estimator, env_kwargs, rank, seed, monitor_dir, worker=False, append=False):
    def make():
        if worker:
            # Ctrl-C reaches every process of the terminal's group: the workers ignore it and
            # the main process, which saves a checkpoint, closes them (otherwise they die
            # first and the close fails with a broken pipe)
            import signal
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        import torch
        torch.set_num_threads(1)
        import gymnasium as gym
        import envs  # noqa: F401  (registers the ids)
        from stable_baselines3.common.monitor import Monitor
        env = gym.make(TASK_IDS[task], estimator=estimator, **env_kwargs)
        # a resumed run appends: the episodes logged before the interrupt stay
        env = Monitor(env, _monitor_file(monitor_dir, rank, append), override_existing=not append)
        env.reset(seed=seed + rank)
        env.action_space.seed(seed + rank)
        return env
    return make


def _interrupt_safe_subproc_vec_env(fns):
    """A ``SubprocVecEnv`` whose ``close`` cannot hang after a Ctrl-C inside ``step_wait``.

    SB3's ``close`` first reads one pending step result from every worker; when the
    KeyboardInterrupt arrived after some of them were already read, it waits forever for a
    result that never comes. Here the pending results are left unread: each worker finishes
    its step, reads "close" and exits; a worker that does not is terminated."""
    from stable_baselines3.common.vec_env import SubprocVecEnv

    class InterruptSafeSubprocVecEnv(SubprocVecEnv):
        def close(self):
            if self.closed:
                return
            for remote in self.remotes:
                try:
                    remote.send(("close", None))
                except OSError:        # the worker is already gone
                    pass
            for process in self.processes:
                process.join(timeout=30)
                if process.is_alive():
                    process.terminate()
                    process.join()
            for remote in self.remotes:
                remote.close()
            self.waiting = False
            self.closed = True

    return InterruptSafeSubprocVecEnv(fns, start_method="forkserver" if sys.platform != "win32" else "spawn")


def make_vec_env(task, estimator, n_envs, seed, env_kwargs=None, monitor_dir=None, subprocess=True, append=False,
                 batched=False):
    """``n_envs`` Monitor-wrapped environments in a ``SubprocVecEnv`` (or ``DummyVecEnv``;
    ``batched``: all in one process and one physics client, envs/vector.py);
    ``append``: the Monitor files are continued, not overwritten."""
    require_import("controllers.rl.make_vec_env", "rl")
    from stable_baselines3.common.vec_env import DummyVecEnv
    if batched:
        import gymnasium as gym

        import envs  # noqa: F401  (registers the ids)
        from envs.vector import SB3VecEnv
        from stable_baselines3.common.vec_env import VecMonitor
        venv = SB3VecEnv(gym.make_vec(TASK_IDS[task], num_envs=n_envs, vectorization_mode="vector_entry_point",
                                      estimator=estimator, **dict(env_kwargs or {})))
        venv.seed(seed)
        return VecMonitor(venv, _monitor_file(monitor_dir, 0, append) if monitor_dir else None)
    sub = subprocess and n_envs > 1
    fns = [_make_env_fn(task, estimator, dict(env_kwargs or {}), i, seed, monitor_dir, worker=sub, append=append)
           for i in range(n_envs)]
    if sub:
        return _interrupt_safe_subproc_vec_env(fns)
    return DummyVecEnv(fns)


def _algo_class(algo):
    from stable_baselines3 import PPO, SAC
    return {"ppo": PPO, "sac": SAC}[algo]


def _checkpoints(ckpt_dir):
    """The checkpoints in ``ckpt_dir``, newest (most steps) first."""
    d = Path(ckpt_dir)
    if not d.is_dir():
        return []
    found = []
    for f in d.glob("ckpt_*_steps.zip"):
        try:
            found.append((int(f.stem.split("_")[1]), f))
        except (IndexError, ValueError):
            continue
    return [f for _, f in sorted(found, reverse=True)]


def _latest_checkpoint(ckpt_dir):
    found = _checkpoints(ckpt_dir)
    return found[0] if found else None


def _checkpoint_stats(ckpt):
    """The normalisation statistics file written beside checkpoint ``ckpt``."""
    return ckpt.with_name(ckpt.name.replace("ckpt_", "ckpt_vecnormalize_").replace(".zip", ".npz"))


def _checkpoint_replay(ckpt):
    """The replay buffer (SAC) written beside checkpoint ``ckpt``."""
    return ckpt.with_name(ckpt.name.replace("ckpt_", "ckpt_replay_").replace(".zip", ".npz"))


def _check_hyperparams(override, hp, algo, task):
    """Each override has the type of the YAML entry it replaces (a number for a number, an
    integer for an integer, ...) and a sane range; a ValueError names the entry."""
    unknown = sorted(set(override) - set(hp))
    if unknown:
        raise ValueError(f"unknown hyperparameter(s) {', '.join(unknown)} for {algo} on {task}; "
                         f"accepted (controllers/hyperparams/{algo}.yml): {', '.join(sorted(hp))}")
    import math
    import numbers
    positive = {"learning_rate", "n_steps", "batch_size", "n_epochs", "buffer_size", "train_freq",
                "gradient_steps", "n_timesteps", "n_envs", "clip_range", "tau"}
    unit = {"gamma", "gae_lambda", "tau"}
    for name, value in override.items():
        default = hp[name]
        if isinstance(default, bool):
            ok, what = isinstance(value, bool), "true or false"
        elif isinstance(default, numbers.Number) or name == "ent_coef":
            is_num = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
            if name == "ent_coef" and isinstance(value, str) and isinstance(default, str):
                ok, what = value == "auto" or value.startswith("auto_"), "a number >= 0 or 'auto'"
            elif isinstance(default, int) and not isinstance(default, bool) and name not in ("learning_rate",):
                ok, what = is_num and float(value) == int(value), "an integer"
            else:
                ok, what = is_num, "a finite number"
            if ok and name in positive:
                ok, what = value > 0, what + " > 0"
            if ok and name in unit:
                ok, what = 0 < value <= 1, what + " in (0, 1]"
            if ok and name in ("ent_coef", "learning_starts") and not isinstance(value, str):
                ok, what = value >= 0, what + " >= 0"
        else:
            ok, what = isinstance(value, type(default)), f"a {type(default).__name__}"
        if not ok:
            raise ValueError(f"hyperparameter {name} must be {what}, got {value!r}")
        if name == "policy_kwargs":
            _check_policy_kwargs(value, algo)
        if isinstance(default, int) and not isinstance(default, bool) and isinstance(value, float) \
                and name != "learning_rate":
            override[name] = int(value)


#: policy_kwargs a run may set (SB3's MlpPolicy arguments given as plain values; the ones
#: that take classes, activation_fn or optimizer_class, are not read from text; use_sde and
#: the gSDE-only squash_output, full_std, use_expln belong to the algorithm's use_sde), by kind
POLICY_FLAGS = ("ortho_init", "share_features_extractor", "normalize_images")
#: the keys of a net_arch dict, the actor's and the critic's layers: PPO's either or both
#: (a missing one has none), SAC's both
NET_ARCH_KEYS = {"ppo": {"pi", "vf"}, "sac": {"pi", "qf"}}


def _check_policy_kwargs(kw, algo):
    """policy_kwargs before any work (SB3 refused a bad one with a TypeError once the
    environments were running): known names of the algorithm's MlpPolicy, each its kind."""
    import inspect
    import math
    from stable_baselines3 import PPO, SAC

    def layers(x):
        return isinstance(x, list) and all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in x)
    cls = (PPO if algo == "ppo" else SAC).policy_aliases["MlpPolicy"]
    names = set(inspect.signature(cls.__init__).parameters)
    settable = names & ({"net_arch", "log_std_init", "clip_mean", "n_critics"} | set(POLICY_FLAGS))
    for key, v in kw.items():
        if key not in settable:
            raise ValueError(f"hyperparameter policy_kwargs: {key!r} is not accepted for {algo}; accepted: "
                             f"{', '.join(sorted(settable))}")
        if key == "net_arch":
            keys = NET_ARCH_KEYS[algo]
            ok = layers(v) or (isinstance(v, dict) and bool(v) and set(v) <= keys and (algo == "ppo" or set(v) == keys)
                               and all(layers(x) for x in v.values()))
            what = (f"a list of layer sizes (integers >= 1), or a dict of such lists with keys "
                    f"{' and '.join(sorted(keys))}{' (either or both)' if algo == 'ppo' else ''}")
        elif key in POLICY_FLAGS:
            ok, what = isinstance(v, bool), "true or false"
        elif key == "n_critics":
            ok, what = isinstance(v, int) and not isinstance(v, bool) and v >= 1, "an integer >= 1"
        else:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and \
                (key != "clip_mean" or v > 0)
            what = "a finite number" + (" > 0" if key == "clip_mean" else "")
        if not ok:
            raise ValueError(f"hyperparameter policy_kwargs: {key} must be {what}, got {v!r}")


#: ``init_from`` value that starts training from a clone of the PID controller
TEACHER = "pid"


def _collect_teacher(model, venv, teacher, steps, sac, progress):
    """Run ``teacher`` for ``steps`` steps of ``venv``: the lists of raw observations, actions,
    (normalised) rewards and dones per step; SAC: each transition also into the replay buffer."""
    from tqdm.auto import tqdm
    n = venv.num_envs
    teacher.reset()
    venv.reset()
    raw = venv.get_original_obs()
    obs, acts, rews, dones = [], [], [], []
    for _ in tqdm(range(-(-steps // n)), desc=f"cloning {type(teacher).__name__}", unit="step", unit_scale=n,
                  disable=not progress, leave=False):
        a = np.asarray(teacher.act(raw), dtype=np.float32).reshape(n, -1)
        obs.append(raw.copy())
        acts.append(a)
        _, r, done, infos = venv.step(a)
        nxt = venv.get_original_obs()
        if sac:     # as SB3 stores a transition: raw observations and rewards, the true last state
            last = nxt.copy()
            for i in np.flatnonzero(done):
                last[i] = venv.unnormalize_obs(infos[i]["terminal_observation"])
            model.replay_buffer.add(raw, last, a, venv.get_original_reward(), done, infos)
        raw = nxt
        rews.append(r.copy())
        dones.append(done.copy())
        for i in np.flatnonzero(done):
            teacher.reset(i)
    return obs, acts, rews, dones


def _minimise(module, loss_of, batches, epochs, lr):
    """Adam on ``module``'s parameters, in training mode: ``epochs`` passes over ``batches()``,
    ``loss_of(idx)`` per batch. Returns the last epoch's summed loss (each batch's times its size)."""
    import torch
    opt = torch.optim.Adam(module.parameters(), lr=lr)
    module.set_training_mode(True)
    for _ in range(epochs):
        total = 0.0
        for idx in batches():
            loss = loss_of(idx)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
    module.set_training_mode(False)
    return total


def _fit_sac_actor(model, x, y, batches, epochs, lr, action_std):
    """SAC's actor: mean action to ``y`` by least squares, log std to log(action_std).
    Returns (action MSE, the last epoch's summed loss)."""
    import torch
    actor = model.actor
    target_log_std = float(np.log(action_std))

    def loss_of(idx):
        mean, log_std, _ = actor.get_action_dist_params(x[idx])
        return ((torch.tanh(mean) - y[idx]) ** 2).mean() + ((log_std - target_log_std) ** 2).mean()

    total = _minimise(actor, loss_of, batches, epochs, lr)
    with torch.no_grad():
        mse = float(((actor(x, deterministic=True) - y) ** 2).mean())
    return mse, total


def _fit_ppo_policy(model, x, y, rews, dones, batches, epochs, lr, action_std):
    """PPO's policy by maximum likelihood of ``y``, its value function to the discounted
    returns of the teacher's episodes (cut by the end of collection: bootstrap 0), its std
    at least ``action_std``. Returns (action MSE, the last epoch's summed loss)."""
    import torch
    returns = np.zeros_like(rews)
    g = np.zeros(rews.shape[1])
    for t in range(len(rews) - 1, -1, -1):
        g = rews[t] + model.gamma * g * (1.0 - dones[t])
        returns[t] = g
    ret = torch.as_tensor(returns.reshape(-1).astype(np.float32))
    policy = model.policy

    def loss_of(idx):
        values, logp, _ = policy.evaluate_actions(x[idx], y[idx])
        return -logp.mean() + 0.5 * ((values.flatten() - ret[idx]) ** 2).mean()

    total = _minimise(policy, loss_of, batches, epochs, lr)
    with torch.no_grad():
        policy.log_std.clamp_(min=float(np.log(action_std)))
        mse = float(((policy.get_distribution(x).distribution.mean - y) ** 2).mean())
    return mse, total


def clone_teacher(model, venv, teacher, steps, epochs=30, batch_size=256, action_std=0.15, lr=1e-3,
                  seed=0, progress=True, log=print):
    """Behaviour cloning: run ``teacher`` (a ``Controller``) for ``steps`` environment steps
    in ``venv`` (a ``VecNormalize``; its statistics learn from these steps), then fit the
    policy of ``model`` to the teacher's actions, with an action std of ``action_std`` (PPO: at
    least that) so that the learner still explores.

    PPO: policy by maximum likelihood, value function to the discounted (normalised) returns
    of the teacher's episodes. SAC: the actor's mean action by least squares and its std to
    ``action_std``; the teacher's transitions go into the replay buffer, and the critics are
    fitted to them for as many gradient steps as the actor had (``epochs`` passes of
    ``batch_size``) with the cloned actor as the policy (SAC's own critic loss), so that the
    first actor updates follow a critic that knows the clone. Returns the number of steps
    collected."""
    require_import("controllers.rl.clone_teacher", "rl")
    import torch
    sac = hasattr(model, "replay_buffer")
    obs, acts, rews, dones = _collect_teacher(model, venv, teacher, steps, sac, progress)
    x = torch.as_tensor(venv.normalize_obs(np.concatenate(obs)).astype(np.float32))
    y = torch.as_tensor(np.concatenate(acts))
    rng = np.random.default_rng(seed)
    def batches():
        perm = rng.permutation(len(x))
        return (torch.as_tensor(perm[k:k + batch_size]) for k in range(0, len(x), batch_size))
    if sac:
        mse, total = _fit_sac_actor(model, x, y, batches, epochs, lr, action_std)
        _fit_sac_critics(model, epochs * -(-len(x) // batch_size))
        model.learning_starts = 0       # the buffer is filled: no random-action warm-up
    else:
        mse, total = _fit_ppo_policy(model, x, y, np.array(rews), np.array(dones), batches, epochs, lr, action_std)
    if log:
        log(f"cloned {type(teacher).__name__} from {len(x)} steps: action MSE {mse:.2e}, "
            f"final loss {total / len(x):.3f}")
    return len(x)


def _fit_sac_critics(model, steps):
    """SAC's critic update (soft Bellman targets from the target critics and the current
    actor, entropy coefficient as it stands) for ``steps`` gradient steps on the replay
    buffer, the actor and the entropy coefficient held."""
    import torch
    import torch.nn.functional as F
    from stable_baselines3.common.utils import polyak_update
    ent = (torch.exp(model.log_ent_coef.detach()) if model.ent_coef_optimizer is not None
           else model.ent_coef_tensor)
    model.critic.set_training_mode(True)
    for _ in range(steps):
        data = model.replay_buffer.sample(model.batch_size, env=model._vec_normalize_env)
        with torch.no_grad():
            nxt, nxt_logp = model.actor.action_log_prob(data.next_observations)
            q_next = torch.cat(model.critic_target(data.next_observations, nxt), dim=1).min(dim=1, keepdim=True)[0]
            discount = data.discounts if data.discounts is not None else model.gamma
            target = data.rewards + (1 - data.dones) * discount * (q_next - ent * nxt_logp.reshape(-1, 1))
        loss = 0.5 * sum(F.mse_loss(q, target) for q in model.critic(data.observations, data.actions))
        model.critic.optimizer.zero_grad()
        loss.backward()
        model.critic.optimizer.step()
        polyak_update(model.critic.parameters(), model.critic_target.parameters(), model.tau)
    model.critic.set_training_mode(False)


class _RunFiles:
    """The files a training run writes in its run directory, each atomically."""

    def __init__(self, model, run_dir, ckpt_dir, normalize):
        self.model, self.run_dir, self.ckpt_dir, self.normalize = model, run_dir, ckpt_dir, normalize

    BEST_FILES = ("best_model.zip", "best_vecnormalize.npz")

    def _digests(self):
        """sha256 of each best file present ({name: hex})."""
        import hashlib
        return {n: hashlib.sha256((self.run_dir / n).read_bytes()).hexdigest() for n in self.BEST_FILES
                if (self.run_dir / n).is_file()}

    def save_best(self, mean_reward):
        # model, statistics, then the score that names them the best, with their digests: each
        # file atomic, and the set whole only when the score's digests are the files'
        model = self.model
        save_model(model, self.run_dir / "best_model.zip")
        if self.normalize:
            save_normalization(model.get_vec_normalize_env(), self.run_dir / "best_vecnormalize.npz")
        atomic_write(self.run_dir / "best.json", lambda f: f.write(json.dumps(
            {"mean_reward": mean_reward, "timesteps": int(model.num_timesteps), "sha256": self._digests()}).encode()))

    def recorded_best(self):
        """best.json's score (mean_reward, timesteps) if it names the best files there now, else
        None: a kill between the files of a new best left a model with another moment's
        statistics, or a score with neither (a run of an older version, without digests, is
        taken as it was)."""
        try:
            best = json.loads((self.run_dir / "best.json").read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(best, dict) or not (self.run_dir / "best_model.zip").is_file():
            return None
        digests = best.pop("sha256", None)
        if digests is not None and digests != self._digests():
            return None
        return best

    def ensure_best(self):
        """No evaluated model to ship (no evaluation ran: a very short run, or a resume of one
        that ends before the first evaluation; or a best set a kill left incomplete): the last
        model is the one shipped, and a score that names other files is removed."""
        if self.recorded_best() is None:
            (self.run_dir / "best.json").unlink(missing_ok=True)
            save_model(self.model, self.run_dir / "best_model.zip")
            if self.normalize:
                save_normalization(self.model.get_vec_normalize_env(), self.run_dir / "best_vecnormalize.npz")

    def save_checkpoint(self):
        # statistics first, then the zip: a checkpoint is listed only once both are whole
        model = self.model
        self.ckpt_dir.mkdir(parents=True, exist_ok=True)
        path = self.ckpt_dir / f"ckpt_{model.num_timesteps}_steps.zip"
        if self.normalize:
            save_normalization(model.get_vec_normalize_env(), _checkpoint_stats(path))
        buffer = getattr(model, "replay_buffer", None)
        if buffer is not None:      # (SAC) beside the newest checkpoint only: tens of MB each
            save_replay(buffer, _checkpoint_replay(path))
        save_model(model, path)
        if buffer is not None:
            for old in self.ckpt_dir.glob("ckpt_replay_*_steps.npz"):
                if old != _checkpoint_replay(path):
                    old.unlink(missing_ok=True)
        return path


def _callbacks(saver, eval_env, eval_freq, checkpoint_freq, eval_episodes, eval_seed):
    """(checkpoint callback, evaluation callback) of a run; the evaluation's ``eval_time``
    adds up the seconds its episodes took inside learn()."""
    from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

    class SaveBestStats(BaseCallback):
        # beside the best model: its normalisation statistics and its score, so that a
        # resumed run only replaces it with a better one
        def _on_step(self):
            saver.save_best(float(self.parent.best_mean_reward))
            return True

    class Checkpoint(BaseCallback):
        def _on_step(self):
            if self.n_calls % checkpoint_freq == 0:
                saver.save_checkpoint()
            return True

    class TimedEval(EvalCallback):
        # the evaluation episodes run inside learn(): time them apart from training
        eval_time = 0.0

        def _on_step(self):
            t = time.perf_counter()
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                # every evaluation on the same episodes (eval_seed): the best model is chosen
                # by comparing policies, not episodes (one shipped policy scored 85.8, 85.7
                # and 99.3 on three consecutive 5-episode draws)
                self.eval_env.seed(eval_seed)
            ok = super()._on_step()
            self.eval_time += time.perf_counter() - t
            return ok

    ev = TimedEval(eval_env, callback_on_new_best=SaveBestStats(), n_eval_episodes=eval_episodes,
                   eval_freq=eval_freq, best_model_save_path=None, log_path=str(saver.run_dir),
                   deterministic=True, verbose=0)
    return Checkpoint(), ev


def _new_model(venv, init, algo, policy, hp, normalize, extra, seed, log):
    """(venv, model) of a run that does not resume: the weights and statistics of ``init``
    (zip, statistics) if given, else a fresh ``algo`` model with the hyperparameters ``hp``."""
    from stable_baselines3.common.vec_env import VecNormalize
    if init is not None:
        if normalize:
            venv = vec_normalize(load_normalization(init[1]), venv, True)
        model = load_model(init[0], env=venv, algo=algo, extra=extra)
        model.set_random_seed(seed)
        model.num_timesteps = 0
        log(f"starting from the weights of {init[0]}")
        return venv, model
    if normalize:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=True, gamma=hp.get("gamma", 0.99))
    return venv, _algo_class(algo)(policy, venv, seed=seed, device="cpu", verbose=0, **hp)


def _clone_pid(model, venv, eval_env, bc_steps, seed, progress, log):
    """Behaviour-clone the PID into ``model`` (``clone_teacher``); returns the steps collected."""
    from controllers.pid import PID
    # the teacher runs at the training environments' control rate (env_kwargs may set it)
    teacher = PID.for_env(eval_env.venv.envs[0])
    return clone_teacher(model, venv, teacher, bc_steps, seed=seed, progress=progress, log=log)


def _learn(saver, timesteps, callback, ev, reset, progress, n_envs, log):
    """model.learn up to ``timesteps`` in all; Ctrl-C saves a checkpoint first. Returns (wall
    s, steps/s, steps/s of training alone: the evaluation episodes' time taken out)."""
    from stable_baselines3.common.logger import Logger
    model = saver.model
    # no printed or written log (the run keeps its learning curve in evaluations.npz): SB3's
    # default logger would leave an empty folder in the temp directory on every learn()
    model.set_logger(Logger(None, []))
    remaining = timesteps - model.num_timesteps
    t0, steps0 = time.perf_counter(), model.num_timesteps
    try:
        if remaining > 0:
            model.learn(remaining, callback=callback, reset_num_timesteps=reset, progress_bar=progress)
    except KeyboardInterrupt:
        path = saver.save_checkpoint()
        log(f"\ninterrupted at {model.num_timesteps} steps: checkpoint saved to {path}; "
            f"continue with --resume")
        raise
    wall = time.perf_counter() - t0
    done = model.num_timesteps - steps0
    rate = done / wall if wall > 0 else float("nan")
    train_wall = wall - ev.eval_time
    train_rate = done / train_wall if train_wall > 0 else float("nan")
    log(f"trained {done} steps in {wall:.0f} s: {train_rate:.0f} environment steps/s of training "
        f"({n_envs} envs; {rate:.0f}/s including {ev.eval_time:.0f} s of evaluation episodes)")
    return wall, rate, train_rate


def _run_hyperparams(algo, task, override):
    """(hyperparameters for the run, the same as recorded in its JSON): the YAML file's, with
    the entries of ``override`` (checked: only names the file has) replacing them."""
    hp = hyperparams(algo, task)
    override = dict(override or {})
    _check_hyperparams(override, hp, algo, task)
    hp.update(override)
    # a deep copy: SB3's SAC writes use_sde into the policy_kwargs it is given, which the
    # record then held (and a grid's --resume took for another setting)
    return hp, copy.deepcopy(hp)


def run_size(hp, timesteps, n_envs):
    """(timesteps, n_envs) of a run: those given, else the hyperparameters' (``hp``: the YAML
    entry's), whose n_envs is 2 where the entry gives none. Not checked (_check_run_size)."""
    return (hp["n_timesteps"] if timesteps is None else timesteps,
            hp.get("n_envs", 2) if n_envs is None else n_envs)


def _evaluate_start(saver, venv, eval_env, ev, eval_episodes, log):
    """The starting policy (a clone or ``init_from``) is the first candidate for the best
    model: training must beat it."""
    from stable_baselines3.common.evaluation import evaluate_policy
    eval_env.obs_rms = venv.obs_rms
    rewards, lengths = evaluate_policy(saver.model, eval_env, n_eval_episodes=eval_episodes, deterministic=True,
                                       return_episode_rewards=True)
    mean_reward = float(np.mean(rewards))
    saver.save_best(mean_reward)
    ev.best_mean_reward = mean_reward
    # the first point of the run's evaluation log (evaluations.npz: its learning curve)
    ev.evaluations_timesteps.append(int(saver.model.num_timesteps))
    ev.evaluations_results.append(list(rewards))
    ev.evaluations_length.append(list(lengths))
    _save_evaluations(ev)
    log(f"the starting policy's evaluation: mean reward {mean_reward:.2f}")


def _save_evaluations(ev):
    """The evaluation log as EvalCallback writes it (``<run>/evaluations.npz``), atomically."""
    def write(f):
        np.savez(f, timesteps=np.asarray(ev.evaluations_timesteps), results=np.asarray(ev.evaluations_results),
                 ep_lengths=np.asarray(ev.evaluations_length))
    atomic_write(ev.log_path + ".npz", write)


def _resume_evaluations(ev, run_dir, timesteps):
    """A resumed run continues its evaluation log (EvalCallback would start it over): the
    rows up to the checkpoint's ``timesteps`` (later ones were of the lost part of the run)."""
    path = Path(run_dir) / "evaluations.npz"
    if not path.is_file():
        return
    try:
        with np.load(path, allow_pickle=False) as d:
            keep = d["timesteps"] <= timesteps
            rows = d["timesteps"][keep], d["results"][keep], d["ep_lengths"][keep]
    except (OSError, ValueError, KeyError) as e:
        warnings.warn(f"{path} cannot be read ({e}); the resumed run starts a new evaluation log",
                      RuntimeWarning, stacklevel=3)
        return
    ev.evaluations_timesteps = [int(t) for t in rows[0]]
    ev.evaluations_results = [list(r) for r in rows[1]]
    ev.evaluations_length = [list(n) for n in rows[2]]


def _write_run_json(stem, best_eval, meta):
    """<stem>.json: ``meta`` plus the observation size, the best evaluation (or None) and the time."""
    from envs.sphere import OBS_NAMES
    meta = dict(meta, obs_size=len(OBS_NAMES), best_eval=best_eval, saved=time.strftime("%Y-%m-%d %H:%M:%S"))
    atomic_write(str(stem) + ".json", lambda f: f.write(json.dumps(meta, indent=2).encode()))


def _check_run_size(timesteps, n_envs, eval_freq, checkpoint_freq, eval_episodes):
    """(timesteps, n_envs) as ints, or a ValueError naming the argument at fault."""
    if isinstance(timesteps, (float, np.floating)) and float(timesteps).is_integer():
        timesteps = int(timesteps)      # YAML's n_timesteps: 1.0e+5
    timesteps = integer("timesteps", timesteps, 1)
    n_envs = integer("n_envs", n_envs, 1, 256)
    for name, v in (("eval_freq", eval_freq), ("checkpoint_freq", checkpoint_freq)):
        integer(name, v, 1, allow_none=True)
    integer("eval_episodes", eval_episodes, 1)
    return timesteps, n_envs


def _checked_env_kwargs(task, estimator, env_kwargs):
    """A copy of ``env_kwargs`` (None: {}), each entry checked by the environment's rules."""
    if not isinstance(env_kwargs, (dict, type(None))):
        raise ValueError(f"env_kwargs must be a dict of environment arguments, got {env_kwargs!r}")
    env_kwargs = dict(env_kwargs or {})
    if "task" in env_kwargs or "estimator" in env_kwargs:
        raise ValueError("env_kwargs must not hold task or estimator (they are arguments of their own)")
    _check_env_kwargs(task, estimator, env_kwargs)
    return env_kwargs


def _prepare_run_dir(run_dir, ckpt_dir, resume, overwrite, log):
    """Refuse to mix runs: an earlier run's checkpoints need ``resume`` or ``overwrite`` (which
    moves the earlier run directory aside); ``resume`` needs a checkpoint; both together are refused.
    A new run moves aside any earlier run directory, also one without checkpoints (killed
    before its first): its best.json and best_model.zip would otherwise be shipped as this run's."""
    if resume and overwrite:
        raise ValueError("resume continues the run in the work directory and overwrite starts it over: give one")
    run_dir = Path(run_dir)
    if not resume and _latest_checkpoint(ckpt_dir) is not None and not overwrite:
        raise FileExistsError(f"{ckpt_dir} holds checkpoints of an earlier run: --resume to continue it, or "
                              f"--overwrite to start over (the earlier run directory is then kept aside)")
    if not resume and run_dir.is_dir() and any(run_dir.iterdir()):
        aside = stamp = f"{run_dir}.old-{time.strftime('%Y%m%d-%H%M%S')}"
        n = 1
        while Path(aside).exists():         # (a second start in the same second)
            n += 1
            aside = f"{stamp}-{n}"
        os.replace(run_dir, aside)
        log(f"the earlier run directory is now {aside}")
    if resume and not _checkpoints(ckpt_dir):
        raise FileNotFoundError(f"--resume: no checkpoint in {ckpt_dir}; train without --resume first")


EVAL_SEED_OFFSET = 10_000       # the evaluation environment's seed: the run's plus this
# numpy's and gymnasium's seeds are below 2**32; make_vec_env seeds the n_envs environments from seed on
SEED_MAX = 2**32 - 1 - EVAL_SEED_OFFSET - 256
IDENTITY_FILE = "run.json"      # in <stem>.run/: what a resumed run must continue with


def _identity(p, init_from):
    """What makes a run the same run (``IDENTITY_FILE``): a resume with any other would mix
    two trainings under one label."""
    return {"algo": p.algo, "task": p.task, "estimator": p.estimator, "env_kwargs": p.env_kwargs,
            "seed": p.seed, "n_envs": p.n_envs, "hyperparams": p.used_hp, "init_from": _start_name(init_from)}


def _start_name(init_from):
    """``init_from`` as the identity records it: the start policy's absolute zip path (one
    file, however it was spelled), "pid", or None."""
    if init_from is None or init_from == TEACHER:
        return init_from
    try:
        return str(_resolve(init_from)[1].resolve())
    except PolicyError:
        return os.fspath(init_from)


def _check_identity(p, init_from):
    """Before any work: with ``resume``, the run directory's identity against this call's (a
    difference is a ValueError listing each; ``init_from`` None on a resume means "as before";
    a run of an older version without the file is not checked)."""
    if not p.resume:
        return
    path = p.run_dir / IDENTITY_FILE
    try:
        recorded = json.loads(path.read_text())
    except FileNotFoundError:           # (a run of an older version: this resume records it)
        return
    except (OSError, ValueError) as e:
        raise ValueError(f"--resume: {path} cannot be read ({e}): it records what the run was") from None
    now = json.loads(json.dumps(_identity(p, init_from)))     # (as the file holds it: lists, not tuples)
    if init_from is None:
        now["init_from"] = recorded.get("init_from")
    diff = [f"{k}: {recorded.get(k)!r} before, {v!r} now" for k, v in now.items() if recorded.get(k) != v]
    if diff:
        raise ValueError(f"--resume: {p.run_dir} is another run ({'; '.join(diff)}); resume it with its own "
                         f"settings, or train without --resume into another --out")


def _record_identity(p, init_from):
    """``IDENTITY_FILE`` of a new run (a resumed one keeps its own; one of an older version,
    without the file, gets it from its first resume)."""
    if not p.resume or not (p.run_dir / IDENTITY_FILE).is_file():
        write_text(p.run_dir / IDENTITY_FILE, json.dumps(_identity(p, init_from), indent=2))


def _init_source(init_from, algo, task, trusted, log):
    """(zip, statistics) of the policy ``init_from`` names, checked to be of ``algo``; a warning
    for a file outside the package unless ``trusted``."""
    _, init_zip, init_json, init_vn = _resolve(init_from)
    if not init_zip.is_file():
        raise FileNotFoundError(f"init_from: policy file {init_zip} does not exist")
    if not trusted and not _in_package(init_zip):
        warnings.warn(f"init_from: {init_zip} is outside the package: model files can be crafted to run code; "
                      f"it is read with pickled entries refused, but start only from files you trust "
                      f"(trusted=True, --trusted, silences this)", UntrustedPolicyWarning, stacklevel=3)
    init_meta = json.loads(init_json.read_text()) if init_json.is_file() else {}
    if init_meta.get("algo", algo) != algo:
        raise ValueError(f"init_from: {init_zip} is a {init_meta.get('algo')} policy; this run trains {algo}")
    if init_meta.get("task", task) != task:
        # allowed (same observation and action spaces): the last four observations mean
        # "the angle to steer to" in both tasks, so a track policy is a head start
        log(f"init_from: {init_zip} was trained for task {init_meta.get('task')!r}; fine-tuning it for {task!r}")
    return init_zip, init_vn


def _resume_replay(model, ckpt, log):
    """SAC's replay buffer as the checkpoint left it; without it (a checkpoint of an older
    version, or one the newest replaced) a warning: the run goes on learning from an empty
    buffer, past learning_starts."""
    try:
        n = load_replay(model.replay_buffer, _checkpoint_replay(ckpt))
    except PolicyError as e:
        warnings.warn(f"{e}: the resumed run's replay buffer starts empty", RuntimeWarning, stacklevel=3)
        log(f"the replay buffer of {ckpt.name} cannot be read; it starts empty")
        return
    log(f"replay buffer: {n} transitions")


def _readable_start(init, resume, ckpt_dir, normalize, algo, extra, log):
    """Read the start policy ``init`` or, with ``resume``, find the newest checkpoint that
    loads (returned; None without resume), before anything is written or any environment is
    started: a crafted or corrupt file is refused first. A truncated or corrupt checkpoint
    (the machine died while it was written by an older version) falls back to the one before,
    with a warning."""
    if init is not None:
        load_model(init[0], algo=algo, extra=extra)
        if normalize:
            load_normalization(init[1])
    if not resume:
        return None
    for ckpt in _checkpoints(ckpt_dir):
        try:
            if normalize:
                load_normalization(_checkpoint_stats(ckpt))
            load_model(ckpt, algo=algo, extra=extra)
        except PolicyError as e:
            warnings.warn(f"checkpoint {ckpt.name} cannot be read ({e}); trying the one before",
                          RuntimeWarning, stacklevel=3)
            log(f"checkpoint {ckpt.name} cannot be read; trying the one before")
            continue
        return ckpt
    raise FileNotFoundError(f"--resume: no readable checkpoint in {ckpt_dir}")


def _history(stem):
    """The commands of the runs a resumed run continues (from its stem's JSON; [] if none)."""
    old_json = Path(str(stem) + ".json")
    if not old_json.is_file():
        return []
    try:
        old = json.loads(old_json.read_text())
        return list(old.get("history") or [old.get("command")])
    except (OSError, ValueError):
        return []


def _plan(algo, task, estimator, timesteps, seed, out, env_kwargs, resume, eval_episodes, eval_freq,
          checkpoint_freq, n_envs, init_from, bc_steps, hyperparams_override, vec_env):
    """Every setting of a run, checked (a ValueError names the one at fault) before any work."""
    import fusion
    from types import SimpleNamespace
    choice("algorithm", algo, ALGOS)
    choice("task", task, tuple(TASK_IDS))
    choice("estimator", estimator, tuple(fusion.available()) + ("truth",))
    hp, used_hp = _run_hyperparams(algo, task, hyperparams_override)
    timesteps, n_envs = _check_run_size(*run_size(hp, timesteps, n_envs), eval_freq, checkpoint_freq, eval_episodes)
    hp.pop("n_timesteps")
    hp.pop("n_envs", None)
    choice("vec_env", vec_env, VEC_ENVS)
    seed = integer("seed", seed, 0, SEED_MAX)
    clone = init_from == TEACHER and not resume
    if clone:
        integer("bc_steps", bc_steps, 1)
    stem = Path(out) if out is not None else new_run_stem(algo, task, estimator)
    run_dir = Path(str(stem) + ".run")
    return SimpleNamespace(
        algo=algo, task=task, estimator=estimator, seed=seed, timesteps=timesteps, n_envs=n_envs, hp=hp,
        used_hp=used_hp, normalize=hp.pop("normalize", True), policy=hp.pop("policy", "MlpPolicy"),
        env_kwargs=_checked_env_kwargs(task, estimator, env_kwargs), stem=stem, run_dir=run_dir,
        ckpt_dir=run_dir / "checkpoints", resume=resume, clone=clone, bc_steps=bc_steps, vec_env=vec_env,
        eval_episodes=eval_episodes,
        # the callbacks count calls, one per step of all n_envs environments
        eval_freq=max(1, int((eval_freq or max(10_000, timesteps // 10)) // n_envs)),
        checkpoint_freq=max(1, int((checkpoint_freq or max(20_000, timesteps // 10)) // n_envs)),
        extra={"train_freq": hp["train_freq"]} if "train_freq" in hp else {})


def _run_envs(p):
    """(training venv, evaluation env) of the plan ``p``, unwrapped by VecNormalize."""
    venv = make_vec_env(p.task, p.estimator, p.n_envs, p.seed, p.env_kwargs, monitor_dir=str(p.run_dir / "monitor"),
                        append=p.resume, subprocess=p.vec_env == "subproc", batched=p.vec_env == "batched")
    return venv, make_vec_env(p.task, p.estimator, 1, p.seed + EVAL_SEED_OFFSET, p.env_kwargs, subprocess=False)


def _start_model(p, venv, eval_env, init, start_ckpt, progress, log):
    """(venv, eval_env, model, PID steps cloned) of a run: resumed from ``start_ckpt``, started
    from ``init`` or fresh, then cloned from the PID if the plan says so."""
    from stable_baselines3.common.vec_env import VecNormalize
    if p.resume:
        if p.normalize:
            venv = vec_normalize(load_normalization(_checkpoint_stats(start_ckpt)), venv, True)
        model = load_model(start_ckpt, env=venv, algo=p.algo, extra=p.extra)
        log(f"resuming from {start_ckpt} at {model.num_timesteps} steps")
        if getattr(model, "replay_buffer", None) is not None:
            _resume_replay(model, start_ckpt, log)
    else:
        venv, model = _new_model(venv, init, p.algo, p.policy, p.hp, p.normalize, p.extra, p.seed, log)
    if p.normalize:
        eval_env = VecNormalize(eval_env, norm_obs=True, norm_reward=False, training=False)
    bc_collected = 0
    if p.clone:
        if not p.normalize:
            raise ValueError(f"init_from={TEACHER!r} needs normalize: true in the hyperparameters")
        bc_collected = _clone_pid(model, venv, eval_env, p.bc_steps, p.seed, progress, log)
        if "learning_starts" in p.used_hp:
            p.used_hp["learning_starts"] = model.learning_starts     # the JSON says what ran
    return venv, eval_env, model, bc_collected


def _train_model(p, model, venv, eval_env, init, start_ckpt, progress, log):
    """Evaluate the start, learn to ``p.timesteps``, save the last checkpoint and make sure
    there is a best model; returns (wall s, steps/s, training steps/s, evaluation s)."""
    from stable_baselines3.common.callbacks import CallbackList
    saver = _RunFiles(model, p.run_dir, p.ckpt_dir, p.normalize)
    eval_seed = p.seed + EVAL_SEED_OFFSET      # the evaluation environment's (_run_envs)
    ckpt, ev = _callbacks(saver, eval_env, p.eval_freq, p.checkpoint_freq, p.eval_episodes, eval_seed)
    best = saver.recorded_best() if start_ckpt is not None else None
    if best is not None:
        ev.best_mean_reward = float(best["mean_reward"])
    if start_ckpt is not None:
        _resume_evaluations(ev, p.run_dir, model.num_timesteps)
    if p.clone or init is not None:
        eval_env.seed(eval_seed)       # the episodes TimedEval evaluates on
        _evaluate_start(saver, venv, eval_env, ev, p.eval_episodes, log)
    wall, rate, train_rate = _learn(saver, p.timesteps, CallbackList([ckpt, ev]), ev,
                                    start_ckpt is None and init is None, progress, p.n_envs, log)
    saver.save_checkpoint()
    saver.ensure_best()
    return wall, rate, train_rate, ev.eval_time


def _recorded_start(p):
    """The start of a run resumed from its checkpoint (which is given no ``init_from``), as
    its identity file recorded it: the start policy's zip name, the PID clone, or None."""
    try:
        start = json.loads((p.run_dir / IDENTITY_FILE).read_text()).get("init_from")
    except (OSError, ValueError):
        return None
    if start is None or start == TEACHER:
        return start if start is None else f"{TEACHER} (behaviour cloning)"
    return Path(start).name


def _publish(p, command, init, start_ckpt, bc_collected, times):
    """Copy the best model (and its statistics) to the stem and write its JSON."""
    wall, rate, train_rate, eval_time = times
    p.stem.parent.mkdir(parents=True, exist_ok=True)
    _copy(p.run_dir / "best_model.zip", str(p.stem) + ".zip")
    if p.normalize:
        _copy(p.run_dir / "best_vecnormalize.npz", str(p.stem) + NORM_SUFFIX)
    history = _history(p.stem) if start_ckpt is not None else []
    _write_run_json(p.stem, _RunFiles(None, p.run_dir, p.ckpt_dir, p.normalize).recorded_best(), {
        "command": command, "history": history + [command], "algo": p.algo, "task": p.task,
        "estimator": p.estimator, "estimator_params": estimator_config(p.estimator, p.env_kwargs),
        "env_id": TASK_IDS[p.task], "env_kwargs": p.env_kwargs, "timesteps": p.timesteps,
        "seed": p.seed, "n_envs": p.n_envs, "hyperparams": p.used_hp, "normalize": p.normalize,
        "init_from": (f"{TEACHER} (behaviour cloning, {bc_collected} steps)" if p.clone
                      else _recorded_start(p) if init is None else str(Path(init[0]).name)),
        "wall_time_s": round(wall, 1), "steps_per_s": round(rate, 1), "training_steps_per_s": round(train_rate, 1),
        "eval_time_s": round(eval_time, 1)})


def train(algo: str, task: str, estimator: str, timesteps: int | None = None, seed: int = 0,
          out: str | os.PathLike | None = None, env_kwargs: dict[str, Any] | None = None, resume: bool = False,
          eval_episodes: int = 5, eval_freq: int | None = None, checkpoint_freq: int | None = None,
          n_envs: int | None = None, progress: bool = True, command: str | None = None,
          init_from: str | None = None, overwrite: bool = False, bc_steps: int = 60_000,
          hyperparams_override: dict[str, Any] | None = None, log: Callable[[str], Any] = print,
          trusted: bool = False, vec_env: str = "subproc") -> Path:
    """Train ``algo`` on ``task`` with ``estimator`` in the loop; returns the policy stem
    (``out``; default ``new_run_stem(...)``: ``./logs/<algo>/<env-id>_<n>/``; nothing is
    written into the package: ``install_policy`` does that).

    All arguments are checked (a ValueError names the one at fault: ``n_envs``, a bad
    ``env_kwargs`` entry, a hyperparameter) before any work. Work directory ``<stem>.run/``
    keeps the Monitor logs, the checkpoints (every ``checkpoint_freq`` steps, with their
    VecNormalize statistics) and the best model of the evaluation callback. Ctrl-C saves a
    checkpoint before leaving; ``resume=True`` continues from the newest checkpoint to the same
    total ``timesteps``. ``init_from``: a policy stem of the same algorithm (and observation
    space) whose weights and normalisation statistics start the training (a name of
    ``available_policies()`` or a path; outside the package an ``UntrustedPolicyWarning`` unless
    ``trusted``) (fine-tuning: a policy trained on the true attitude adapted to an estimator, or
    a track policy as the start of a waypoints one); ``timesteps`` then counts the new steps
    only. ``init_from="pid"`` starts from a behaviour clone of the PID controller
    (``clone_teacher``, ``bc_steps`` teacher steps; for SAC they also fill the replay buffer).
    The starting policy (clone or ``init_from``) is evaluated first and kept as the best model
    unless training beats it. ``hyperparams_override``: a dict replacing entries of the YAML
    file's (only names it has), e.g. ``{"learning_rate": 1e-4}`` for a fine-tune.
    """
    require_import("controllers.rl.train", "rl")
    import torch
    torch.set_num_threads(1)
    p = _plan(algo, task, estimator, timesteps, seed, out, env_kwargs, resume, eval_episodes, eval_freq,
              checkpoint_freq, n_envs, init_from, bc_steps, hyperparams_override, vec_env)
    _prepare_run_dir(p.run_dir, p.ckpt_dir, resume, overwrite, log)
    _check_identity(p, init_from)
    init = None
    if init_from is not None and init_from != TEACHER and not resume:
        init = _init_source(init_from, algo, task, trusted, log)
    start_ckpt = _readable_start(init, resume, p.ckpt_dir, p.normalize, algo, p.extra, log)
    p.run_dir.mkdir(parents=True, exist_ok=True)
    _record_identity(p, init_from)
    venv, eval_env = _run_envs(p)
    try:
        venv, eval_env, model, bc_collected = _start_model(p, venv, eval_env, init, start_ckpt, progress, log)
        times = _train_model(p, model, venv, eval_env, init, start_ckpt, progress, log)
    finally:
        venv.close()
        eval_env.close()
    _publish(p, command, init, start_ckpt, bc_collected, times)
    return p.stem


def _copy(src, dst):
    data = Path(src).read_bytes()
    atomic_write(dst, lambda f: f.write(data))


def _check_env_kwargs(task, estimator, env_kwargs):
    """Build one environment in this process, so that a bad argument is a ValueError naming
    it here, not a dead worker later."""
    import gymnasium as gym
    import envs  # noqa: F401
    try:
        env = gym.make(TASK_IDS[task], estimator=estimator, **env_kwargs)
    except TypeError as e:          # an unknown argument name
        raise ValueError(f"env_kwargs: {e}") from None
    except ValueError as e:
        raise ValueError(f"env_kwargs: {e}") from None
    env.close()


def install_policy(stem: str | os.PathLike, name: str | None = None) -> Path:
    """Copy the policy ``stem`` (``.zip``, statistics, ``.json``) into the package's policies
    (``POLICY_DIR``) as ``name`` (default: the stem's name), each file atomically; returns the
    installed stem."""
    stem, zip_path, json_path, vn_path = _resolve(stem)
    if not zip_path.is_file():
        raise PolicyError(f"policy file {zip_path} does not exist")
    if name is not None and (not isinstance(name, str) or not name or name.startswith(".")
                             or any(c in name for c in "/\\") or Path(name).name != name):
        raise ValueError(f"name must be a plain file name (no folder, not hidden), got {name!r}")
    dest = POLICY_DIR / (name or stem.name)
    for src, suffix in ((vn_path, NORM_SUFFIX), (json_path, ".json"), (zip_path, ".zip")):
        if src.is_file():
            _copy(src, str(dest) + suffix)
            if suffix == ".zip":        # shipped policies carry no optimizer moments
                drop_optimizer_state(str(dest) + suffix)
        else:       # a file of the policy installed before would be read with the new one
            Path(str(dest) + suffix).unlink(missing_ok=True)
    return dest


class PolicyController(Controller):
    """A trained SB3 policy behind the ``Controller`` interface (deterministic actions,
    observations normalised with the statistics it was trained with)."""

    def __init__(self, model: Any, obs_rms: Any = None, clip_obs: float = 10.0, epsilon: float = 1e-8,
                 meta: dict[str, Any] | None = None, path: str | os.PathLike | None = None) -> None:
        self.model = model
        self.obs_rms = obs_rms
        self.clip_obs = clip_obs
        self.epsilon = epsilon
        self.meta = dict(meta or {})
        self.path = path
        self.task = self.meta.get("task")

    def __repr__(self):
        return f"PolicyController({str(self.path)!r})"

    def act(self, obs: ArrayLike) -> np.ndarray:
        o, single = obs_batch(obs)
        if o.shape[1] != self.model.observation_space.shape[0]:
            raise ValueError(f"policy {self.path} takes observations of size "
                             f"{self.model.observation_space.shape[0]}, got {o.shape[1]}")
        if self.obs_rms is not None:
            o = np.clip((o - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.epsilon),
                        -self.clip_obs, self.clip_obs)
        a, _ = self.model.predict(o.astype(np.float32), deterministic=True)
        a = np.clip(a, -1.0, 1.0)
        return a[0] if single else a


def _resolve(path: Any) -> tuple[Path, Path, Path, Path]:
    """(stem, zip, json, statistics) of a policy: a name of ``available_policies()`` (the
    package's, from any folder) or a path to the stem or the ``.zip``."""
    if path is None or isinstance(path, bool) or not isinstance(path, (str, os.PathLike)):
        raise PolicyError(f"policy must be a name of controllers.available_policies() or a path "
                          f"(str or os.PathLike), got {path!r}")
    text = os.fspath(path)
    if not text:
        raise PolicyError("policy must be a name of controllers.available_policies() or a path, got ''")
    p = Path(text)
    if p.name == text and not p.suffix == ".zip" and (POLICY_DIR / (text + ".zip")).is_file():
        p = POLICY_DIR / text          # a bare name: the shipped policy, not the current folder
    stem = p.with_suffix("") if p.suffix == ".zip" else p
    return stem, Path(str(stem) + ".zip"), Path(str(stem) + ".json"), Path(str(stem) + NORM_SUFFIX)


def _in_package(path):
    try:
        return Path(path).resolve().parent == POLICY_DIR.resolve()
    except OSError:
        return False


def load_policy(path: str | os.PathLike, env: Any = None, trusted: bool = False) -> PolicyController:
    """Load a policy: ``path`` a name of ``available_policies()`` (shipped in the package) or
    the path of a stem or ``.zip`` saved by ``train``. With ``env``, also check that the policy
    was trained for its task and observation space.

    Nothing in the files is unpickled (``controllers.policy_io``): the zip's pickled entries
    are refused, the weights read as tensors only, the statistics as plain arrays. A policy
    from outside the package still warns (``UntrustedPolicyWarning``) that a model file is a
    program's input to trust: pass ``trusted=True`` for files you made yourself."""
    require_import("controllers.rl.load_policy", "rl")
    import torch
    torch.set_num_threads(1)
    stem, zip_path, json_path, vn_path = _resolve(path)
    if not zip_path.is_file():
        bare = Path(os.fspath(path)).name == os.fspath(path)
        hint = f"; shipped policies: {', '.join(available_policies())}" if bare else ""
        raise PolicyError(f"policy file {zip_path} does not exist{hint}")
    flag("trusted", trusted)
    if not trusted and not _in_package(zip_path):
        warnings.warn(f"loading policy {zip_path} from outside the package: model files can be crafted to run "
                      f"code; it is read with pickled entries refused, but load only files you trust "
                      f"(trusted=True silences this)", UntrustedPolicyWarning, stacklevel=2)
    meta = {}
    if json_path.is_file():
        try:
            with open(json_path) as f:
                meta = json.load(f)
        except (OSError, ValueError) as e:
            raise PolicyError(f"policy metadata {json_path} is corrupt: {e}") from None
        if not isinstance(meta, dict):
            raise PolicyError(f"policy metadata {json_path} is not a JSON object")
    algo = meta.get("algo")
    model = load_model(zip_path, algo=algo if algo in ALGOS else None)
    obs_rms, clip, eps = None, 10.0, 1e-8
    if vn_path.is_file():
        stats = load_normalization(vn_path)
        if stats["norm_obs"]:
            obs_rms = _RunningStats(stats["obs_mean"], stats["obs_var"])
        clip, eps = stats["clip_obs"], stats["epsilon"]
    elif meta.get("normalize", False):
        raise PolicyError(f"policy {zip_path} was trained with normalisation but {vn_path} is missing")
    shape = model.observation_space.shape
    if obs_rms is not None and tuple(np.shape(obs_rms.mean)) != tuple(shape):
        raise PolicyError(f"{vn_path} has statistics for observations of shape {np.shape(obs_rms.mean)}, "
                          f"the model takes {shape}")
    if env is not None:
        base = env.unwrapped
        if tuple(env.observation_space.shape) != tuple(shape):
            raise PolicyError(f"policy {zip_path} was trained for observations of shape {shape}; "
                              f"this environment gives {env.observation_space.shape}")
        if meta.get("task") not in (None, base.task):
            raise PolicyError(f"policy {zip_path} was trained for task {meta.get('task')!r}; "
                              f"this environment's task is {base.task!r}")
    return PolicyController(model, obs_rms, clip, epsilon=eps, meta=meta, path=zip_path)


class _RunningStats:
    """The mean and variance a ``PolicyController`` normalises with."""

    def __init__(self, mean, var):
        self.mean, self.var = mean, var
