#!/usr/bin/env python
"""Train a stable-baselines3 policy for the spherical robot with an estimator in the loop.

    .venv/bin/python scripts/train.py --algo ppo --task waypoints --estimator ekf
    .venv/bin/python scripts/train.py --algo ppo --task track --estimator truth --timesteps 300000 --seed 0
    .venv/bin/python scripts/train.py ... --resume        # continue after Ctrl-C or a crash

Writes controllers/policies/<algo>-<task>-<estimator>.{zip,vecnormalize.pkl,json} (or
--out STEM); the work directory <stem>.run/ keeps checkpoints, Monitor logs and the
evaluation log. Hyperparameters: controllers/hyperparams/<algo>.yml. After training the
policy is evaluated with controllers.evaluate() (--eval-episodes) and the result goes into
the JSON.
"""
import argparse
import json
import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controllers import rl                       # noqa: E402
from controllers.evaluation import evaluate        # noqa: E402


def _value(text):
    """A number if it reads as one (PyYAML would keep "1e-4" a string), else YAML (lists,
    dicts, true/false)."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    import yaml
    return yaml.safe_load(text)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", required=True, help=f"one of {', '.join(rl.ALGOS)}")
    ap.add_argument("--task", required=True, help=f"one of {', '.join(rl.TASK_IDS)}")
    ap.add_argument("--estimator", required=True, help="a name of fusion.available() or 'truth'")
    ap.add_argument("--timesteps", type=int, default=None, help="default: the YAML file's n_timesteps")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-envs", type=int, default=None, help="default: the YAML file's n_envs")
    ap.add_argument("--out", default=None, help="policy stem (default controllers/policies/<algo>-<task>-<estimator>)")
    ap.add_argument("--resume", action="store_true", help="continue from the newest checkpoint")
    ap.add_argument("--overwrite", action="store_true",
                    help="start over although the work directory holds checkpoints (they are kept aside)")
    ap.add_argument("--init-from", default=None,
                    help="start from this policy's weights and statistics (same algo), e.g. "
                         "controllers/policies/ppo-waypoints-truth; or 'pid': from a behaviour clone "
                         "of the PID controller (sac: its steps also fill the replay buffer)")
    ap.add_argument("--bc-steps", type=int, default=60_000,
                    help="with --init-from pid: environment steps of the PID teacher to clone")
    ap.add_argument("--hyperparams", nargs="+", default=[], metavar="NAME=VALUE",
                    help="override entries of the YAML file, e.g. learning_rate=1e-4 n_epochs=5")
    ap.add_argument("--eval-episodes", type=int, default=10, help="final evaluation episodes (0: none)")
    ap.add_argument("--env-kwargs", default="{}", help="JSON dict of extra environment arguments")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    try:
        env_kwargs = json.loads(a.env_kwargs)
        if not isinstance(env_kwargs, dict):
            raise ValueError
    except ValueError:
        ap.error(f"--env-kwargs must be a JSON object, got {a.env_kwargs!r}")
    override = {}
    for item in a.hyperparams:
        name, sep, value = item.partition("=")
        if not sep or not name:
            ap.error(f"--hyperparams takes NAME=VALUE items, got {item!r}")
        override[name] = _value(value)
    command = "python scripts/train.py " + " ".join(shlex.quote(x) for x in (sys.argv[1:] if argv is None else argv))
    try:
        stem = rl.train(a.algo, a.task, a.estimator, timesteps=a.timesteps, seed=a.seed, out=a.out,
                        env_kwargs=env_kwargs, resume=a.resume, n_envs=a.n_envs, progress=not a.no_progress,
                        command=command, init_from=a.init_from, overwrite=a.overwrite,
                        bc_steps=a.bc_steps, hyperparams_override=override)
    except KeyboardInterrupt:
        return 130
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"policy: {stem}.zip")
    if a.eval_episodes > 0:
        ctrl = rl.load_policy(stem)
        res = evaluate(ctrl, dict(env_kwargs, task=a.task, estimator=a.estimator), episodes=a.eval_episodes,
                       seed=1_000_000)
        summary = {k: v["mean"] for k, v in res["summary"].items()}
        meta_path = Path(str(stem) + ".json")
        meta = json.loads(meta_path.read_text())
        meta["final_evaluation"] = {"episodes": a.eval_episodes, "seed": 1_000_000, "mean": summary}
        meta_path.write_text(json.dumps(meta, indent=2))
        print("final evaluation:", ", ".join(f"{k} {v:.3g}" for k, v in summary.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
