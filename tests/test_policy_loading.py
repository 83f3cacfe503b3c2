"""Issue 17: policies by name, loading without running code from the files, rl-zoo3-style
training runs that never write into the package unless asked."""
import base64
import hashlib
import json
import os
import pickle
import subprocess
import sys
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
from controllers import rl                       # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = "ppo-waypoints-truth"


class Evil:
    """Unpickling this creates the marker file: what a crafted model would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_available_policies_and_no_pickle_shipped():
    names = rl.available_policies()
    assert SHIPPED in names and len(names) >= 18
    assert not list(rl.POLICY_DIR.glob("*.pkl"))
    for n in names:
        assert (rl.POLICY_DIR / f"{n}{rl.NORM_SUFFIX}").is_file()


def test_load_by_name_from_any_folder(tmp_path):
    code = ("import warnings; warnings.simplefilter('error'); import numpy as np; "
            "from controllers import load_policy, available_policies; "
            f"p = load_policy({SHIPPED!r}); print(p.act(np.zeros(14, np.float32)).shape, len(available_policies()))")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split()[:2] == ["(2,)", str(len(rl.available_policies()))]


def test_path_outside_package_warns(tmp_path):
    for suffix in (".zip", ".json", rl.NORM_SUFFIX):
        (tmp_path / f"p{suffix}").write_bytes((rl.POLICY_DIR / f"{SHIPPED}{suffix}").read_bytes())
    with pytest.warns(rl.UntrustedPolicyWarning, match="outside the package"):
        a = rl.load_policy(tmp_path / "p")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        b = rl.load_policy(str(tmp_path / "p.zip"), trusted=True)
        c = rl.load_policy(rl.POLICY_DIR / SHIPPED)     # a path into the package: no warning
    obs = np.random.default_rng(0).uniform(-1, 1, (20, 14)).astype(np.float32)
    np.testing.assert_array_equal(a.act(obs), b.act(obs))
    np.testing.assert_array_equal(a.act(obs), c.act(obs))
    with pytest.raises(ValueError, match="trusted"):
        rl.load_policy(SHIPPED, trusted="yes")


def _copy_policy(dst_stem, data_edit=None, pth=None):
    src = rl.POLICY_DIR / f"{SHIPPED}.zip"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(str(dst_stem) + ".zip", "w") as zout:
        for name in zin.namelist():
            raw = zin.read(name)
            if name == "data" and data_edit:
                d = json.loads(raw)
                data_edit(d)
                raw = json.dumps(d).encode()
            if pth and name == "policy.pth":
                raw = pth
            zout.writestr(name, raw)
    for suffix in (".json", rl.NORM_SUFFIX):
        Path(str(dst_stem) + suffix).write_bytes((rl.POLICY_DIR / f"{SHIPPED}{suffix}").read_bytes())


def _serialized(obj):
    return {":type:": "<class 'x'>", ":serialized:": base64.b64encode(pickle.dumps(obj)).decode()}


def _crafted(tmp_path, key=None, pth=None):
    """A copy of the shipped policy at ``tmp_path/crafted`` with code that would create
    ``tmp_path/marker`` if it ran: in the model's entry ``key``, or in the weights ``pth(marker)``
    returns. Returns (marker, stem)."""
    marker, stem = tmp_path / "marker", tmp_path / "crafted"
    edit = (lambda d: d.__setitem__(key, _serialized(Evil(marker)))) if key else None
    _copy_policy(stem, data_edit=edit, pth=pth(marker) if pth else None)
    return marker, stem


def _refused(stem, match):
    with pytest.raises(rl.PolicyError, match=match):
        rl.load_policy(stem, trusted=True)


@pytest.mark.parametrize("key", ["observation_space", "action_space", "lr_schedule", "clip_range", "evil_entry"])
def test_crafted_serialized_entry_refused(tmp_path, key):
    marker, stem = _crafted(tmp_path, key)
    _refused(stem, "refused")
    assert not marker.exists()


@pytest.mark.parametrize("key", ["_last_obs", "ep_info_buffer", "rollout_buffer_class", "policy_class"])
def test_crafted_entry_never_read(tmp_path, key):
    """Entries SB3 recreates (run-time buffers) or that the algorithm fixes (its policy class)
    are replaced without reading them: the policy loads, acts as the shipped one, and the
    pickled code never runs."""
    marker, stem = _crafted(tmp_path, key)
    obs = np.random.default_rng(1).uniform(-1, 1, (10, 14)).astype(np.float32)
    np.testing.assert_array_equal(rl.load_policy(stem, trusted=True).act(obs), rl.load_policy(SHIPPED).act(obs))
    assert not marker.exists()


def test_crafted_weights_refused(tmp_path):
    import io
    import torch

    def weights(marker):
        buf = io.BytesIO()
        torch.save({"w": Evil(marker)}, buf)
        return buf.getvalue()
    marker, stem = _crafted(tmp_path, pth=weights)
    _refused(stem, "not a plain SB3 model")
    assert not marker.exists()


def test_crafted_statistics_refused(tmp_path):
    marker, stem = _crafted(tmp_path)
    stats = dict(np.load(rl.POLICY_DIR / f"{SHIPPED}{rl.NORM_SUFFIX}"))
    stats["obs_mean"] = np.array([Evil(marker)], dtype=object)
    with open(str(stem) + rl.NORM_SUFFIX, "wb") as f:
        np.savez(f, **stats)
    _refused(stem, "not plain arrays")
    # a legacy pickle beside the zip is never opened
    os.remove(str(stem) + rl.NORM_SUFFIX)
    with open(str(stem) + ".vecnormalize.pkl", "wb") as f:
        pickle.dump(Evil(marker), f)
    _refused(stem, "is missing")
    assert not marker.exists()


def test_crafted_init_from_and_resume_refused(tmp_path):
    marker, stem = _crafted(tmp_path, "observation_space")
    kw = dict(timesteps=64, n_envs=1, progress=False, env_kwargs={"episode_s": 1.0}, log=lambda *a: None)
    with pytest.warns(rl.UntrustedPolicyWarning, match="init_from"), pytest.raises(rl.PolicyError, match="refused"):
        rl.train("ppo", "waypoints", "truth", out=tmp_path / "ft", init_from=stem, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error", rl.UntrustedPolicyWarning)
        with pytest.raises(rl.PolicyError, match="refused"):
            rl.train("ppo", "waypoints", "truth", out=tmp_path / "ft2", init_from=stem, trusted=True, **kw)
    # --resume: every checkpoint crafted -> no readable checkpoint, nothing run
    ck = tmp_path / "r.run" / "checkpoints"
    ck.mkdir(parents=True)
    _copy_policy(ck / "ckpt_64_steps", data_edit=lambda d: d.__setitem__("evil", _serialized(Evil(marker))))
    os.replace(ck / f"ckpt_64_steps{rl.NORM_SUFFIX}", ck / "ckpt_vecnormalize_64_steps.npz")
    with pytest.warns(RuntimeWarning, match="ckpt_64_steps"), pytest.raises(FileNotFoundError, match="no readable"):
        rl.train("ppo", "waypoints", "truth", out=tmp_path / "r", resume=True, **kw)
    assert not marker.exists()


def _tree_hash(folder):
    h = hashlib.sha256()
    for p in sorted(Path(folder).iterdir()):
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()


def test_train_cli_rl_zoo_layout_and_install(tmp_path, monkeypatch):
    from controllers import train_cli
    before = _tree_hash(rl.POLICY_DIR)
    args = ["--algo", "ppo", "--env", "SphereBotTrack-v1", "--estimator", "truth", "-n", "64", "-f", str(tmp_path),
            "--eval-episodes", "0", "--eval-freq", "1000000", "--no-progress", "--seed", "3",
            "--hyperparams", "n_steps:64", "batch_size=32", "--env-kwargs", "episode_s:1.0"]
    assert train_cli.main(args) == 0
    assert train_cli.main(args) == 0
    for n in (1, 2):
        run = tmp_path / "ppo" / f"SphereBotTrack-v1_{n}"
        assert (run / "ppo-track-truth.zip").is_file() and (run / f"ppo-track-truth{rl.NORM_SUFFIX}").is_file()
        meta = json.loads((run / "ppo-track-truth.json").read_text())
        assert meta["seed"] == 3 and meta["hyperparams"]["n_steps"] == 64 and meta["env_kwargs"] == {"episode_s": 1.0}
    assert _tree_hash(rl.POLICY_DIR) == before          # nothing written into the package
    installed = tmp_path / "package_policies"
    installed.mkdir()
    monkeypatch.setattr(rl, "POLICY_DIR", installed)
    assert train_cli.main(args + ["--install-policy"]) == 0
    assert sorted(p.name for p in installed.iterdir()) == ["ppo-track-truth.json", "ppo-track-truth.vecnormalize.npz",
                                                           "ppo-track-truth.zip"]
    # the weights as trained (the optimizer's moments are dropped on install)
    import zipfile
    with zipfile.ZipFile(installed / "ppo-track-truth.zip") as a, \
            zipfile.ZipFile(tmp_path / "ppo" / "SphereBotTrack-v1_3" / "ppo-track-truth.zip") as b:
        assert a.read("policy.pth") == b.read("policy.pth")


def test_help_of_every_command():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for script in ("scripts/train.py", "scripts/compare_estimators.py", "scripts/reproduce_papers.py",
                   "benchmarks/throughput.py", "benchmarks/peers.py"):
        r = subprocess.run([sys.executable, str(ROOT / script), "--help"], capture_output=True, text=True,
                           env=env, timeout=120)
        assert r.returncode == 0 and "usage" in r.stdout, (script, r.stderr[-1000:])
        # every option line has help text after it (argparse puts it on the same or the next line)
        lines = r.stdout.splitlines()
        for i, line in enumerate(lines):
            s = line.strip()
            if s.startswith("-") and not s.startswith("-h"):
                has_text = len(s.split("  ")) > 1 and s.split("  ")[-1].strip()
                nxt = lines[i + 1].strip() if i + 1 < len(lines) else ""
                assert has_text or (nxt and not nxt.startswith("-")), (script, line)


def test_training_environment_is_the_evaluated_robot():
    """train() builds its environments from rl.TASK_IDS: they must be the robot the
    comparison evaluates on (SphereRobotEnv's defaults, the v1 robot), not the -v0 ids,
    which since v1 are the ideal robot (realism='ideal')."""
    pytest.importorskip("pybullet")
    import gymnasium as gym
    import envs  # noqa: F401
    from envs.sphere import SphereRobotEnv
    default = SphereRobotEnv(task="track").realism
    for task, env_id in rl.TASK_IDS.items():
        env = gym.make(env_id, estimator="truth")
        try:
            assert env.unwrapped.task == task
            assert env.unwrapped.realism == default, (env_id, env.unwrapped.realism)
        finally:
            env.close()
        for algo in rl.ALGOS:
            assert rl.hyperparams(algo, task)["n_timesteps"] > 0


def test_install_policy_replaces_every_file(tmp_path, monkeypatch):
    """install_policy copies the stem's files into the package's policies; installing over
    a policy that had statistics with one that has none removes the old statistics (they
    were left behind, and load_policy then normalised the new policy's observations with
    the old policy's statistics)."""
    import shutil
    src = rl.POLICY_DIR / "ppo-track-truth"
    pkg = tmp_path / "policies"
    pkg.mkdir()
    monkeypatch.setattr(rl, "POLICY_DIR", pkg)
    a = tmp_path / "a" / "ppo-track-truth"
    a.parent.mkdir()
    for s in (".zip", rl.NORM_SUFFIX, ".json"):
        shutil.copy(str(src) + s, str(a) + s)
    dest = rl.install_policy(a, "ppo-track-mine")
    assert dest == pkg / "ppo-track-mine"
    for s in (".zip", rl.NORM_SUFFIX, ".json"):
        assert Path(str(dest) + s).read_bytes() == Path(str(a) + s).read_bytes()
    b = tmp_path / "b" / "ppo-track-truth"             # trained without normalisation
    b.parent.mkdir()
    shutil.copy(str(src) + ".zip", str(b) + ".zip")
    meta = json.loads(Path(str(src) + ".json").read_text())
    meta["normalize"] = False
    Path(str(b) + ".json").write_text(json.dumps(meta))
    rl.install_policy(b, "ppo-track-mine")
    assert not Path(str(dest) + rl.NORM_SUFFIX).exists()
    assert rl.load_policy("ppo-track-mine").obs_rms is None


def test_refused_start_policy_writes_nothing(tmp_path):
    """A crafted --init-from policy or statistics is refused before the run writes anything
    (the run folder and its Monitor logs were created, and training environments started,
    before the policy was read); a --resume whose checkpoints are all unreadable leaves the
    run folder as it was (its Monitor logs were opened for appending and cut first)."""
    marker, stem = _crafted(tmp_path, "observation_space")
    kw = dict(timesteps=64, n_envs=1, progress=False, env_kwargs={"episode_s": 1.0}, log=lambda *a: None,
              trusted=True)
    with pytest.raises(rl.PolicyError, match="refused"):
        rl.train("ppo", "waypoints", "truth", out=tmp_path / "ft" / "p", init_from=stem, **kw)
    assert not (tmp_path / "ft").exists()
    _copy_policy(stem)
    Path(str(stem) + rl.NORM_SUFFIX).write_bytes(b"not an npz")
    with pytest.raises(rl.PolicyError, match="corrupt"):
        rl.train("ppo", "waypoints", "truth", out=tmp_path / "ft" / "p", init_from=stem, **kw)
    assert not (tmp_path / "ft").exists()
    run = tmp_path / "r.run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "monitor").mkdir()
    log = run / "monitor" / "0.monitor.csv"
    log.write_bytes(b'#{"t_start": 1}\nr,l,t\n1.0,10,0.5\n2.0,1')          # cut mid-row by a kill
    _copy_policy(run / "checkpoints" / "ckpt_64_steps",
                 data_edit=lambda d: d.__setitem__("evil", _serialized(Evil(marker))))
    os.replace(run / "checkpoints" / f"ckpt_64_steps{rl.NORM_SUFFIX}",
               run / "checkpoints" / "ckpt_vecnormalize_64_steps.npz")
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    with pytest.warns(RuntimeWarning, match="ckpt_64_steps"), pytest.raises(FileNotFoundError, match="no readable"):
        rl.train("ppo", "waypoints", "truth", out=tmp_path / "r", resume=True, **kw)
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
    assert not marker.exists()


@pytest.mark.parametrize("name", ["../escaped", "sub/x", "", ".hidden", "a\\b"])
def test_install_policy_name_is_a_plain_name(tmp_path, monkeypatch, name):
    """install_policy's name is a file name in the package's policies, not a path that
    writes elsewhere ('../escaped' wrote beside the package)."""
    pkg = tmp_path / "pkg" / "policies"
    pkg.mkdir(parents=True)
    monkeypatch.setattr(rl, "POLICY_DIR", pkg)
    shipped = Path(__file__).resolve().parents[1] / "controllers" / "policies" / SHIPPED
    with pytest.raises(ValueError, match="name"):
        rl.install_policy(shipped, name)
    assert sorted(p.name for p in (tmp_path / "pkg").rglob("*")) == ["policies"]


def test_dropping_the_optimizer_state_keeps_the_actions(tmp_path):
    """install_policy ships a policy without Adam's moments (a third of the zip): the weights
    and so the actions are unchanged, and the file still loads (for acting and fine-tuning)."""
    import shutil

    import numpy as np
    from controllers import policy_io, rl
    src = rl.POLICY_DIR / "ppo-track-ekf"
    for s in (".zip", rl.NORM_SUFFIX, ".json"):
        shutil.copy(str(src) + s, tmp_path / ("p" + s))
    before = rl.load_policy(tmp_path / "p", trusted=True)
    policy_io.drop_optimizer_state(tmp_path / "p.zip")
    after = rl.load_policy(tmp_path / "p", trusted=True)
    obs = np.random.default_rng(0).uniform(-1, 1, (20, 14)).astype(np.float32)
    assert all(np.array_equal(before.act(o), after.act(o)) for o in obs)
    model = policy_io.load_model(tmp_path / "p.zip")
    assert model.policy.optimizer.state_dict()["state"] == {}
