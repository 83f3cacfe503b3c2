"""Training, saving and loading stable-baselines3 policies for the spherical robot.

A trained policy is three files with one stem, e.g. ``controllers/policies/ppo-waypoints-ekf``:

- ``<stem>.zip``: the SB3 model (the best one found by the evaluation callback);
- ``<stem>.vecnormalize.pkl``: the ``VecNormalize`` observation statistics it was trained with;
- ``<stem>.json``: the exact command, algorithm, task, estimator, environment arguments,
  timesteps, seed, wall time, training throughput, the observation names and the final
  evaluation.

``load_policy(stem_or_zip)`` returns a ``PolicyController`` (the ``Controller`` interface).
Hyperparameters live in rl-zoo3-style YAML files, ``controllers/hyperparams/<algo>.yml``,
keyed by environment id. Heavy imports (torch, SB3) happen inside the functions, so that
``import controllers`` stays light.
"""
from __future__ import annotations

import json
import os
import pickle
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from controllers.base import Controller, obs_batch

__all__ = ["ALGOS", "TASK_IDS", "POLICY_DIR", "hyperparams", "train", "load_policy", "PolicyController",
           "policy_stem", "PolicyError"]

ALGOS = ("ppo", "sac")
TASK_IDS = {"track": "SphereBotTrack-v0", "waypoints": "SphereBotWaypoints-v0"}
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
POLICY_DIR = Path(__file__).resolve().parent / "policies"


class PolicyError(ValueError):
    """A policy file that is missing, corrupt or does not fit the environment."""


def _check_choice(name, value, accepted):
    if value not in accepted:
        raise ValueError(f"unknown {name} {value!r}; accepted: {', '.join(accepted)}")


def policy_stem(algo, task, estimator, directory=POLICY_DIR):
    """Where ``scripts/train.py`` puts the policy of (algo, task, estimator)."""
    return Path(directory) / f"{algo}-{task}-{estimator}"


def hyperparams(algo, task):
    """The YAML entry of ``algo`` for ``task``'s environment id, as a dict (a copy)."""
    import yaml
    _check_choice("algorithm", algo, ALGOS)
    _check_choice("task", task, tuple(TASK_IDS))
    path = HYPERPARAMS_DIR / f"{algo}.yml"
    with open(path) as f:
        table = yaml.safe_load(f)
    env_id = TASK_IDS[task]
    if env_id not in table:
        raise ValueError(f"{path} has no entry for {env_id}")
    return dict(table[env_id])


def _make_env_fn(task, estimator, env_kwargs, rank, seed, monitor_dir, worker=False):
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
        env = Monitor(env, None if monitor_dir is None else os.path.join(monitor_dir, str(rank)))
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


def make_vec_env(task, estimator, n_envs, seed, env_kwargs=None, monitor_dir=None, subprocess=True):
    """``n_envs`` Monitor-wrapped environments in a ``SubprocVecEnv`` (or ``DummyVecEnv``)."""
    from stable_baselines3.common.vec_env import DummyVecEnv
    sub = subprocess and n_envs > 1
    fns = [_make_env_fn(task, estimator, dict(env_kwargs or {}), i, seed, monitor_dir, worker=sub)
           for i in range(n_envs)]
    if sub:
        return _interrupt_safe_subproc_vec_env(fns)
    return DummyVecEnv(fns)


def _algo_class(algo):
    from stable_baselines3 import PPO, SAC
    return {"ppo": PPO, "sac": SAC}[algo]


def _latest_checkpoint(ckpt_dir):
    d = Path(ckpt_dir)
    if not d.is_dir():
        return None
    best, best_steps = None, -1
    for f in d.glob("ckpt_*_steps.zip"):
        try:
            steps = int(f.stem.split("_")[1])
        except (IndexError, ValueError):
            continue
        if steps > best_steps:
            best, best_steps = f, steps
    return best


#: ``init_from`` value that starts training from a clone of the PID controller
TEACHER = "pid"


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
    import torch
    from tqdm.auto import tqdm
    sac = hasattr(model, "replay_buffer")
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
    x = torch.as_tensor(venv.normalize_obs(np.concatenate(obs)).astype(np.float32))
    y = torch.as_tensor(np.concatenate(acts))
    rng = np.random.default_rng(seed)
    batches = lambda: (torch.as_tensor(idx) for perm in [rng.permutation(len(x))]
                       for idx in (perm[k:k + batch_size] for k in range(0, len(x), batch_size)))
    if sac:
        actor = model.actor
        opt = torch.optim.Adam(actor.parameters(), lr=lr)
        target_log_std = float(np.log(action_std))
        actor.set_training_mode(True)
        for epoch in range(epochs):
            total = 0.0
            for idx in batches():
                mean, log_std, _ = actor.get_action_dist_params(x[idx])
                loss = ((torch.tanh(mean) - y[idx]) ** 2).mean() + ((log_std - target_log_std) ** 2).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
                total += loss.item() * len(idx)
        actor.set_training_mode(False)
        _fit_sac_critics(model, epochs * -(-len(x) // batch_size))
        model.learning_starts = 0       # the buffer is filled: no random-action warm-up
        with torch.no_grad():
            mse = float(((actor(x, deterministic=True) - y) ** 2).mean())
    else:
        rews, dones = np.array(rews), np.array(dones)
        returns = np.zeros_like(rews)
        g = np.zeros(n)
        for t in range(len(rews) - 1, -1, -1):     # episodes cut by the end of collection bootstrap 0
            g = rews[t] + model.gamma * g * (1.0 - dones[t])
            returns[t] = g
        ret = torch.as_tensor(returns.reshape(-1).astype(np.float32))
        policy = model.policy
        opt = torch.optim.Adam(policy.parameters(), lr=lr)
        policy.set_training_mode(True)
        for epoch in range(epochs):
            total = 0.0
            for idx in batches():
                values, logp, _ = policy.evaluate_actions(x[idx], y[idx])
                loss = -logp.mean() + 0.5 * ((values.flatten() - ret[idx]) ** 2).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
                total += loss.item() * len(idx)
        policy.set_training_mode(False)
        with torch.no_grad():
            policy.log_std.clamp_(min=float(np.log(action_std)))
            mse = float(((policy.get_distribution(x).distribution.mean - y) ** 2).mean())
    if log:
        log(f"cloned {type(teacher).__name__} from {len(x)} steps: action MSE {mse:.2e}, final loss {total / len(x):.3f}")
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


def train(algo, task, estimator, timesteps=None, seed=0, out=None, env_kwargs=None, resume=False,
          eval_episodes=5, eval_freq=None, checkpoint_freq=None, n_envs=None, progress=True,
          command=None, init_from=None, overwrite=False, bc_steps=60_000, hyperparams_override=None,
          log=print):
    """Train ``algo`` on ``task`` with ``estimator`` in the loop; returns the policy stem.

    Work directory ``<stem>.run/`` keeps the Monitor logs, the checkpoints (every
    ``checkpoint_freq`` steps, with their VecNormalize statistics) and the best model of
    the evaluation callback. Ctrl-C saves a checkpoint before leaving; ``resume=True``
    continues from the newest checkpoint to the same total ``timesteps``. ``init_from``: a
    policy stem of the same algorithm (and observation space) whose weights and
    normalisation statistics start the training (fine-tuning: a policy trained on the true
    attitude adapted to an estimator, or a track policy as the start of a waypoints one);
    ``timesteps`` then counts the new steps only. ``init_from="pid"`` starts from a
    behaviour clone of the PID controller (``clone_teacher``, ``bc_steps`` teacher steps;
    for SAC they also fill the replay buffer). The starting policy (clone or ``init_from``) is evaluated first and kept as the
    best model unless training beats it. ``hyperparams_override``: a dict replacing entries
    of the YAML file's (only names it has), e.g. ``{"learning_rate": 1e-4}`` for a fine-tune.
    """
    import torch
    torch.set_num_threads(1)
    import fusion
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback, EvalCallback
    from stable_baselines3.common.vec_env import VecNormalize

    _check_choice("algorithm", algo, ALGOS)
    _check_choice("task", task, tuple(TASK_IDS))
    _check_choice("estimator", estimator, tuple(fusion.available()) + ("truth",))
    hp = hyperparams(algo, task)
    override = dict(hyperparams_override or {})
    unknown = sorted(set(override) - set(hp))
    if unknown:
        raise ValueError(f"unknown hyperparameter(s) {', '.join(unknown)} for {algo} on {task}; "
                         f"accepted (controllers/hyperparams/{algo}.yml): {', '.join(sorted(hp))}")
    hp.update(override)
    used_hp = dict(hp)
    default_steps, default_envs = hp.pop("n_timesteps"), hp.pop("n_envs", 2)
    timesteps = int(default_steps if timesteps is None else timesteps)
    if timesteps < 1:
        raise ValueError(f"timesteps must be >= 1, got {timesteps}")
    n_envs = int(default_envs if n_envs is None else n_envs)
    normalize = hp.pop("normalize", True)
    policy = hp.pop("policy", "MlpPolicy")
    env_kwargs = dict(env_kwargs or {})
    stem = Path(out) if out is not None else policy_stem(algo, task, estimator)
    run_dir = Path(str(stem) + ".run")
    ckpt_dir = run_dir / "checkpoints"
    eval_freq = max(1, int((eval_freq or max(10_000, timesteps // 10)) // n_envs))
    checkpoint_freq = max(1, int((checkpoint_freq or max(20_000, timesteps // 10)) // n_envs))

    start_ckpt = None
    if not resume and _latest_checkpoint(ckpt_dir) is not None:
        if not overwrite:
            raise FileExistsError(f"{ckpt_dir} holds checkpoints of an earlier run: --resume to continue it, or "
                                  f"--overwrite to start over (the earlier run directory is then kept aside)")
        aside = Path(f"{run_dir}.old-{time.strftime('%Y%m%d-%H%M%S')}")
        os.replace(run_dir, aside)
        log(f"the earlier run directory is now {aside}")
    if resume:
        start_ckpt = _latest_checkpoint(ckpt_dir)
        if start_ckpt is None:
            raise FileNotFoundError(f"--resume: no checkpoint in {ckpt_dir}; train without --resume first")
    init = None
    clone = init_from == TEACHER and start_ckpt is None
    if clone and (isinstance(bc_steps, bool) or not isinstance(bc_steps, int) or bc_steps < 1):
        raise ValueError(f"bc_steps must be an integer >= 1, got {bc_steps!r}")
    if init_from is not None and init_from != TEACHER and start_ckpt is None:
        _, init_zip, init_json, init_vn = _resolve(init_from)
        if not init_zip.is_file():
            raise FileNotFoundError(f"init_from: policy file {init_zip} does not exist")
        init_meta = json.loads(init_json.read_text()) if init_json.is_file() else {}
        if init_meta.get("algo", algo) != algo:
            raise ValueError(f"init_from: {init_zip} is a {init_meta.get('algo')} policy; this run trains {algo}")
        if init_meta.get("task", task) != task:
            # allowed (same observation and action spaces): the last four observations mean
            # "the angle to steer to" in both tasks, so a track policy is a head start
            log(f"init_from: {init_zip} was trained for task {init_meta.get('task')!r}; fine-tuning it for {task!r}")
        init = (init_zip, init_vn)
    run_dir.mkdir(parents=True, exist_ok=True)

    venv = make_vec_env(task, estimator, n_envs, seed, env_kwargs, monitor_dir=str(run_dir / "monitor"))
    eval_env = make_vec_env(task, estimator, 1, seed + 10_000, env_kwargs, subprocess=False)
    cls = _algo_class(algo)
    try:
        if start_ckpt is not None:
            vn_path = Path(str(start_ckpt).replace("ckpt_", "ckpt_vecnormalize_").replace(".zip", ".pkl"))
            if normalize:
                venv = VecNormalize.load(str(vn_path), venv)
            model = cls.load(str(start_ckpt), env=venv, device="cpu")
            log(f"resuming from {start_ckpt} at {model.num_timesteps} steps")
        elif init is not None:
            if normalize:
                venv = VecNormalize.load(str(init[1]), venv)
                venv.training = True
            model = cls.load(str(init[0]), env=venv, device="cpu")
            model.set_random_seed(seed)
            model.num_timesteps = 0
            log(f"starting from the weights of {init[0]}")
        else:
            if normalize:
                venv = VecNormalize(venv, norm_obs=True, norm_reward=True, gamma=hp.get("gamma", 0.99))
            model = cls(policy, venv, seed=seed, device="cpu", verbose=0, **hp)
        if normalize:
            eval_env = VecNormalize(eval_env, norm_obs=True, norm_reward=False, training=False)
        bc_collected = 0
        if clone:
            from controllers.pid import PID
            if not normalize:
                raise ValueError(f"init_from={TEACHER!r} needs normalize: true in the hyperparameters")
            # the teacher runs at the training environments' control rate (env_kwargs may set it)
            teacher = PID.for_env(eval_env.venv.envs[0])
            bc_collected = clone_teacher(model, venv, teacher, bc_steps, seed=seed, progress=progress, log=log)
            if "learning_starts" in used_hp:
                used_hp["learning_starts"] = model.learning_starts     # the JSON says what ran

        class SaveBestStats(BaseCallback):
            # beside the best model: its normalisation statistics and its score, so that a
            # resumed run only replaces it with a better one
            def _on_step(self):
                if normalize:
                    model.get_vec_normalize_env().save(str(run_dir / "best_vecnormalize.pkl"))
                (run_dir / "best.json").write_text(json.dumps(
                    {"mean_reward": float(self.parent.best_mean_reward), "timesteps": int(model.num_timesteps)}))
                return True

        ckpt = CheckpointCallback(checkpoint_freq, str(ckpt_dir), name_prefix="ckpt", save_vecnormalize=normalize)
        class TimedEval(EvalCallback):
            # the evaluation episodes run inside learn(): time them apart from training
            eval_time = 0.0

            def _on_step(self):
                t = time.perf_counter()
                ok = super()._on_step()
                TimedEval.eval_time += time.perf_counter() - t
                return ok

        ev = TimedEval(eval_env, callback_on_new_best=SaveBestStats(), n_eval_episodes=eval_episodes,
                          eval_freq=eval_freq, best_model_save_path=str(run_dir), log_path=str(run_dir),
                          deterministic=True, verbose=0)
        best_json = run_dir / "best.json"
        if start_ckpt is not None and best_json.is_file() and (run_dir / "best_model.zip").is_file():
            ev.best_mean_reward = float(json.loads(best_json.read_text())["mean_reward"])

        def save_checkpoint():
            ckpt_dir.mkdir(parents=True, exist_ok=True)
            path = ckpt_dir / f"ckpt_{model.num_timesteps}_steps.zip"
            model.save(str(path))
            if normalize:
                model.get_vec_normalize_env().save(str(ckpt_dir / f"ckpt_vecnormalize_{model.num_timesteps}_steps.pkl"))
            return path

        if clone or init is not None:
            # the starting policy is the first candidate for the best model: training must beat it
            from stable_baselines3.common.evaluation import evaluate_policy
            eval_env.obs_rms = venv.obs_rms
            mean_reward, _ = evaluate_policy(model, eval_env, n_eval_episodes=eval_episodes, deterministic=True)
            model.save(str(run_dir / "best_model.zip"))
            venv.save(str(run_dir / "best_vecnormalize.pkl"))
            best_json.write_text(json.dumps({"mean_reward": float(mean_reward), "timesteps": 0}))
            ev.best_mean_reward = float(mean_reward)
            log(f"the starting policy's evaluation: mean reward {mean_reward:.2f}")

        remaining = timesteps - model.num_timesteps
        t0, steps0 = time.perf_counter(), model.num_timesteps
        try:
            if remaining > 0:
                model.learn(remaining, callback=CallbackList([ckpt, ev]), reset_num_timesteps=start_ckpt is None and init is None,
                            progress_bar=progress)
        except KeyboardInterrupt:
            path = save_checkpoint()
            log(f"\ninterrupted at {model.num_timesteps} steps: checkpoint saved to {path}; "
                f"continue with --resume")
            raise
        wall = time.perf_counter() - t0
        done = model.num_timesteps - steps0
        rate = done / wall if wall > 0 else float("nan")
        train_wall = wall - TimedEval.eval_time
        train_rate = done / train_wall if train_wall > 0 else float("nan")
        log(f"trained {done} steps in {wall:.0f} s: {train_rate:.0f} environment steps/s of training "
            f"({n_envs} envs; {rate:.0f}/s including {TimedEval.eval_time:.0f} s of evaluation episodes)")
        save_checkpoint()
        best = run_dir / "best_model.zip"
        if not best.exists():          # no evaluation ran (very short run): ship the last model
            model.save(str(best))
            if normalize:
                model.get_vec_normalize_env().save(str(run_dir / "best_vecnormalize.pkl"))
    finally:
        venv.close()
        eval_env.close()

    stem.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(best, str(stem) + ".zip")
    if normalize:
        shutil.copyfile(run_dir / "best_vecnormalize.pkl", str(stem) + ".vecnormalize.pkl")
    from envs.sphere import OBS_NAMES
    # a resumed run keeps the commands of the runs it continues
    history = []
    old_json = Path(str(stem) + ".json")
    if start_ckpt is not None and old_json.is_file():
        try:
            old = json.loads(old_json.read_text())
            history = list(old.get("history") or [old.get("command")])
        except (OSError, ValueError):
            history = []
    meta = {"command": command, "history": history + [command], "algo": algo, "task": task, "estimator": estimator, "env_id": TASK_IDS[task],
            "env_kwargs": env_kwargs, "timesteps": timesteps, "seed": seed, "n_envs": n_envs,
            "hyperparams": used_hp, "normalize": normalize,
            "init_from": (f"{TEACHER} (behaviour cloning, {bc_collected} steps)" if clone
                          else None if init is None else str(Path(init[0]).name)),
            "wall_time_s": round(wall, 1), "steps_per_s": round(rate, 1), "training_steps_per_s": round(train_rate, 1),
            "eval_time_s": round(TimedEval.eval_time, 1), "obs_size": len(OBS_NAMES),
            "best_eval": json.loads(best_json.read_text()) if best_json.is_file() else None,
            "saved": time.strftime("%Y-%m-%d %H:%M:%S")}
    with open(str(stem) + ".json", "w") as f:
        json.dump(meta, f, indent=2)
    return stem


class PolicyController(Controller):
    """A trained SB3 policy behind the ``Controller`` interface (deterministic actions,
    observations normalised with the statistics it was trained with)."""

    def __init__(self, model, obs_rms=None, clip_obs=10.0, epsilon=1e-8, meta=None, path=None):
        self.model = model
        self.obs_rms = obs_rms
        self.clip_obs = clip_obs
        self.epsilon = epsilon
        self.meta = dict(meta or {})
        self.path = path
        self.task = self.meta.get("task")

    def __repr__(self):
        return f"PolicyController({str(self.path)!r})"

    def act(self, obs):
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


def _resolve(path):
    p = Path(path)
    stem = p.with_suffix("") if p.suffix == ".zip" else p
    return stem, Path(str(stem) + ".zip"), Path(str(stem) + ".json"), Path(str(stem) + ".vecnormalize.pkl")


def load_policy(path, env=None):
    """Load a policy saved by ``train`` (``path``: the stem or the ``.zip``). With ``env``,
    also check that the policy was trained for its task and observation space."""
    import torch
    torch.set_num_threads(1)
    stem, zip_path, json_path, vn_path = _resolve(path)
    if not zip_path.is_file():
        raise PolicyError(f"policy file {zip_path} does not exist")
    meta = {}
    if json_path.is_file():
        try:
            with open(json_path) as f:
                meta = json.load(f)
        except (OSError, ValueError) as e:
            raise PolicyError(f"policy metadata {json_path} is corrupt: {e}") from None
    algo = meta.get("algo")
    try:
        if algo in ALGOS:
            model = _algo_class(algo).load(str(zip_path), device="cpu")
        else:
            from stable_baselines3.common.base_class import BaseAlgorithm  # noqa: F401
            last = None
            for cls in (_algo_class("ppo"), _algo_class("sac")):
                try:
                    model = cls.load(str(zip_path), device="cpu")
                    break
                except Exception as e:      # wrong algorithm class: try the next
                    last = e
            else:
                raise last
    except Exception as e:
        raise PolicyError(f"policy file {zip_path} is corrupt or not an SB3 PPO/SAC model: {e}") from None
    obs_rms, clip = None, 10.0
    if vn_path.is_file():
        try:
            with open(vn_path, "rb") as f:
                vn = pickle.load(f)
            obs_rms, clip = vn.obs_rms, float(vn.clip_obs)
        except Exception as e:
            raise PolicyError(f"normalisation statistics {vn_path} are corrupt: {e}") from None
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
    return PolicyController(model, obs_rms, clip, meta=meta, path=zip_path)
