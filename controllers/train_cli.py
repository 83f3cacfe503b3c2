"""``spherebot-train`` (``scripts/train.py``): train a stable-baselines3 policy for the spherical
robot with an estimator in the loop, with rl-zoo3's flag names.

    spherebot-train --algo ppo --env SphereBotWaypoints-v1 --estimator ekf
    spherebot-train --algo ppo --env track --estimator truth -n 300000 --seed 0
    spherebot-train --algo ppo --env track --estimator truth --resume   # after Ctrl-C or a crash

A run goes to ./logs/<algo>/<env-id>_<n>/ (-f/--log-folder; n one more than the last run):
<algo>-<task>-<estimator>.{zip,vecnormalize.npz,json}, and <stem>.run/ with the checkpoints,
Monitor logs and the evaluation log. Nothing is written into the package unless
--install-policy, and then only after the best evaluation is saved. Hyperparameters:
controllers/hyperparams/<algo>.yml (--hyperparams overrides entries). After training the
policy is evaluated with controllers.evaluate() (--eval-episodes) and the result goes into
the JSON. Every option is checked before any work.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from controllers import rl
from fusion.checks import choice, require


def _value(text):
    """A number if it reads as one (PyYAML would keep "1e-4" a string), else YAML (lists,
    dicts, true/false, strings)."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    import yaml
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def _pairs(items, option):
    """rl-zoo3's ``key:value`` items (``key=value`` too) as a dict, values parsed by ``_value``."""
    out = {}
    for item in items:
        eq, colon = item.find("="), item.find(":")
        cut = eq if eq >= 0 and (colon < 0 or eq < colon) else colon
        name, value = (item[:cut], item[cut + 1:]) if cut > 0 else ("", "")
        if not name.isidentifier():
            raise ValueError(f"{option} takes NAME:VALUE (or NAME=VALUE) items, got {item!r}")
        out[name] = _value(value)
    return out


def _env_kwargs(items):
    """One JSON object, or rl-zoo3's ``key:value`` items."""
    if len(items) == 1 and items[0].lstrip().startswith("{"):
        try:
            d = json.loads(items[0])
        except ValueError as e:
            raise ValueError(f"--env-kwargs: not a JSON object ({e})") from None
        if not isinstance(d, dict):
            raise ValueError(f"--env-kwargs must be a JSON object, got {items[0]!r}")
        return d
    return _pairs(items, "--env-kwargs")


def _task(env):
    """--env: an environment id of rl.TASK_IDS or its task name."""
    ids = {v: k for k, v in rl.TASK_IDS.items()}
    if env in ids:
        return ids[env]
    if env in rl.TASK_IDS:
        return env
    hint = (" (the v0 robot: the v1 id with --env-kwargs realism:ideal)"
            if str(env).endswith("-v0") and str(env)[:-1] + "1" in ids else "")
    raise ValueError(f"--env must be one of {', '.join(list(ids) + list(rl.TASK_IDS))}, got {env!r}{hint}")


def _int(lo, hi=None):
    def parse(text):
        try:
            v = int(float(text)) if float(text) == int(float(text)) else None
        except (ValueError, OverflowError):
            v = None
        if v is None or v < lo or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}{'' if hi is None else f' and <= {hi}'}, "
                                             f"got {text!r}")
        return v
    return parse


def parser():
    import fusion
    ap = argparse.ArgumentParser(prog="spherebot-train", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", required=True, choices=rl.ALGOS, help="the RL algorithm")
    ap.add_argument("--env", "--task", dest="env", required=True, nargs="+", metavar="ENV",
                    help=f"environment id ({', '.join(rl.TASK_IDS.values())}) or its task name "
                         f"({', '.join(rl.TASK_IDS)}); --task is an alias; several: a grid")
    ap.add_argument("--estimator", default=["ekf"], nargs="+",
                    help=f"the attitude estimator in the loop: one of {', '.join(fusion.available())} or "
                         f"'truth' (default: ekf); several: a grid")
    ap.add_argument("-n", "--n-timesteps", "--timesteps", dest="timesteps", nargs="+", default=None,
                    metavar="N", help="total environment steps, or TASK:N items (one per task of a grid); "
                                      "alias: --timesteps (default: the YAML file's n_timesteps)")
    ap.add_argument("--seed", type=_int(0, rl.SEED_MAX), default=[0], nargs="+",
                    help=f"random seed, an integer from 0 to {rl.SEED_MAX} (default: 0); several: a grid")
    ap.add_argument("--n-envs", type=_int(1), default=None, metavar="N",
                    help="parallel environments, >= 1 (default: the YAML file's n_envs)")
    ap.add_argument("--vec-env", choices=rl.VEC_ENVS, default="subproc",
                    help="the training environments: one process each, all in this process, or batched in "
                         "one physics client (default: %(default)s)")
    ap.add_argument("--eval-freq", type=_int(1), default=None, metavar="STEPS",
                    help="evaluate (and keep the best model) every STEPS environment steps "
                         "(default: max(10000, n / 10))")
    ap.add_argument("--eval-episodes", type=_int(0), default=10,
                    help="episodes of the final evaluation written into the JSON (0: none; default: %(default)s)")
    ap.add_argument("--n-eval-episodes", type=_int(1), default=5, metavar="N",
                    help="episodes of each periodic evaluation (default: %(default)s)")
    ap.add_argument("--save-freq", type=_int(1), default=None, metavar="STEPS",
                    help="write a checkpoint every STEPS environment steps (default: max(20000, n / 10))")
    ap.add_argument("-f", "--log-folder", default="logs",
                    help="runs go to LOG_FOLDER/<algo>/<env-id>_<n>/ (default: %(default)s)")
    ap.add_argument("--out", default=None, metavar="STEM",
                    help="the policy stem instead (its run folder: STEM.run/)")
    ap.add_argument("--resume", action="store_true",
                    help="continue the newest run of this algo/env/estimator in the log folder (or --out) "
                         "from its newest readable checkpoint, to the same total -n")
    ap.add_argument("--overwrite", action="store_true",
                    help="with --out: start over although its run folder holds checkpoints (they are kept aside)")
    ap.add_argument("--init-from", default=None, metavar="POLICY",
                    help="start from this policy's weights and statistics (same algo): a shipped name "
                         "(e.g. ppo-waypoints-truth) or a path; or 'pid': from a behaviour clone of the "
                         "PID controller (sac: its steps also fill the replay buffer)")
    ap.add_argument("--trusted", action="store_true",
                    help="--init-from a path outside the package without the warning that model files can carry code")
    ap.add_argument("--bc-steps", type=_int(1), default=60_000,
                    help="with --init-from pid: environment steps of the PID teacher to clone (default: %(default)s)")
    ap.add_argument("--hyperparams", nargs="+", default=[], metavar="NAME:VALUE",
                    help="override entries of the YAML file, e.g. learning_rate:1e-4 n_epochs:5 (NAME=VALUE too)")
    ap.add_argument("--env-kwargs", nargs="+", default=[], metavar="NAME:VALUE",
                    help="extra environment arguments, e.g. episode_s:20 bumps:3, or one JSON object")
    ap.add_argument("--install-policy", action="store_true",
                    help="after training and the final evaluation, copy the policy into the package's "
                         "controllers/policies/ (replacing the shipped one of that name)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")
    _grid_options(ap)
    return ap


def _grid_options(ap):
    ap.add_argument("--backend", choices=("local", "ray"), default=None,
                    help="run the grid (--env x --estimator x --seed; also a single job) on a local process "
                         "pool or on Ray; each job writes LOG_FOLDER/<algo>-<task>-<estimator>[-seed<S>], "
                         "--resume skips the finished ones (default: local when there are several jobs)")
    ap.add_argument("--workers", type=_int(1), default=None, metavar="N",
                    help="grid: jobs at a time (local; default: CPUs / 2, each job runs its environments' "
                         "processes) or the CPUs of a local Ray cluster")
    ap.add_argument("--address", default=None,
                    help="grid on Ray: join the cluster at this address (e.g. auto) instead of starting one; "
                         "implies --backend ray")


def _timesteps(items, tasks):
    """-n: None, one N for every task, or TASK:N items (a dict task -> N)."""
    if items is None:
        return None

    def steps(text, task=None):
        # -n is parsed here, not by an argparse type= (whose errors argparse prefixes with the option)
        try:
            return _int(1)(text)
        except argparse.ArgumentTypeError as e:
            raise ValueError(f"-n/--n-timesteps{'' if task is None else f' ({task}:N)'} {e}") from None
    if len(items) == 1 and ":" not in items[0] and "=" not in items[0]:
        return steps(items[0])
    out = {}
    for task, n in _pairs(items, "-n").items():
        if task not in rl.TASK_IDS:
            raise ValueError(f"-n: unknown task {task!r} in TASK:N; accepted: {', '.join(rl.TASK_IDS)}")
        out[task] = steps(str(n), task)
    missing = [t for t in tasks if t not in out]
    if missing:
        raise ValueError(f"-n gives no steps for task {', '.join(missing)}")
    return out


def _grid(a, ap, tasks, env_kwargs, override, timesteps, argv):
    from controllers import train_grid
    if a.out is not None:
        ap.error("--out names one run; a grid writes LOG_FOLDER/<algo>-<task>-<estimator>[-seed<S>] (-f)")
    try:
        jobs = train_grid.grid_jobs(
            a.algo, tasks, a.estimator, a.seed, a.log_folder, timesteps, init_from=a.init_from,
            final_episodes=a.eval_episodes, env_kwargs=env_kwargs, n_envs=a.n_envs, eval_freq=a.eval_freq,
            checkpoint_freq=a.save_freq, eval_episodes=a.n_eval_episodes, bc_steps=a.bc_steps,
            hyperparams_override=override, trusted=a.trusted, vec_env=a.vec_env)
    except ValueError as e:             # (a start policy template with another field)
        ap.error(f"--init-from: {e}")
    command = " ".join(shlex.quote(x) for x in (sys.argv[1:] if argv is None else argv))
    for j in jobs:
        j["command"] = f"spherebot-train {command}  # grid job {j['task']} {j['estimator']} seed {j['seed']}"
    try:
        train_grid.run_train_grid(jobs, backend=a.backend or "local", workers=a.workers, address=a.address,
                                  resume=a.resume, install=a.install_policy)
    except KeyboardInterrupt:
        return 130
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"spherebot-train: error: {e}", file=sys.stderr)
        return 2
    return 0


def main(argv=None):
    """The command line (``spherebot-train``); returns the exit status. A kill (SIGTERM, as a
    cluster's scheduler sends before it stops a job) unwinds like Ctrl-C: a run saves its
    checkpoint, a grid's jobs save theirs and its workers are stopped, not orphaned; the
    status is then 143. The caller's handler is put back at the end."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        return _main(argv)
    killed = []

    def on_term(*_):
        killed.append(True)
        raise KeyboardInterrupt
    old = signal.signal(signal.SIGTERM, on_term)
    try:
        rc = _main(argv)
    finally:
        signal.signal(signal.SIGTERM, old)
    return 143 if killed and rc == 130 else rc


def _main(argv):
    import fusion
    ap = parser()
    a = ap.parse_args(argv)
    require("spherebot-train", "rl")
    if a.address and a.backend == "local":
        ap.error("--address joins a Ray cluster: give it with --backend ray (or without --backend)")
    if a.address:
        a.backend = "ray"
    if a.backend == "ray":
        require("spherebot-train --backend ray", "ray")
    try:
        tasks = list(dict.fromkeys(_task(e) for e in a.env))
        env_kwargs = _env_kwargs(a.env_kwargs)
        override = _pairs(a.hyperparams, "--hyperparams")
        timesteps = _timesteps(a.timesteps, tasks)
        for est in a.estimator:
            choice("estimator", est, tuple(fusion.available()) + ("truth",))
    except (ValueError, argparse.ArgumentTypeError) as e:
        ap.error(str(e))
    if a.backend is not None or len(tasks) * len(a.estimator) * len(a.seed) > 1:
        return _grid(a, ap, tasks, env_kwargs, override, timesteps, argv)
    if a.workers is not None:
        ap.error("--workers sets how many jobs of a grid run at a time: one job has none to share "
                 "(give --backend local to run it as a grid, or several jobs)")
    if isinstance(timesteps, dict):
        timesteps = timesteps[tasks[0]]
    return _single(a, ap, tasks[0], a.estimator[0], a.seed[0], env_kwargs, override, timesteps, argv)


def _single(a, ap, task, estimator, seed, env_kwargs, override, timesteps, argv):
    try:
        if a.out is not None:
            out = Path(a.out)
        elif a.resume:
            out = rl.latest_run_stem(a.algo, task, estimator, a.log_folder)
            if out is None:
                raise FileNotFoundError(f"--resume: no run of {a.algo}-{task}-{estimator} with checkpoints "
                                        f"in {Path(a.log_folder) / a.algo}; train without --resume first")
        else:
            out = rl.new_run_stem(a.algo, task, estimator, a.log_folder)
    except (ValueError, FileNotFoundError) as e:
        ap.error(str(e))
    command = "spherebot-train " + " ".join(shlex.quote(x) for x in (sys.argv[1:] if argv is None else argv))
    try:
        stem = rl.train(a.algo, task, estimator, timesteps=timesteps, seed=seed, out=out,
                        env_kwargs=env_kwargs, resume=a.resume, n_envs=a.n_envs, progress=not a.no_progress,
                        command=command, init_from=a.init_from, overwrite=a.overwrite, eval_freq=a.eval_freq,
                        checkpoint_freq=a.save_freq, eval_episodes=a.n_eval_episodes,
                        bc_steps=a.bc_steps, hyperparams_override=override, trusted=a.trusted,
                        vec_env=a.vec_env)
    except KeyboardInterrupt:
        return 130
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"spherebot-train: error: {e}", file=sys.stderr)
        return 2
    print(f"policy: {stem}.zip")
    if a.eval_episodes > 0:
        summary = rl.final_evaluation(stem, task, estimator, env_kwargs, a.eval_episodes)
        print("final evaluation:", ", ".join(f"{k} {v:.3g}" for k, v in summary.items()))
    if a.install_policy:
        print(f"installed: {rl.install_policy(stem)}.zip")
    return 0


if __name__ == "__main__":
    sys.exit(main())
