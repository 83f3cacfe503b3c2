"""Saving and loading policies without running code from the files, and atomic writes.

- ``save_normalization`` / ``load_normalization``: a ``VecNormalize``'s statistics as plain
  arrays in an ``.npz`` (read with ``allow_pickle=False``), in place of SB3's pickle.
- ``load_model``: an SB3 PPO/SAC zip with every pickled (``:serialized:``) entry of its
  ``data`` refused: the observation and action spaces are rebuilt from the entry's readable
  fields, the policy class from the algorithm, constant schedules from their printed value,
  and run-time buffers are left to SB3 to recreate; any other pickled entry is an error. The
  weights (``*.pth``) are first read with ``torch.load(weights_only=True)``, so that a file
  holding anything but tensors is refused before SB3 reads it.
- ``atomic_write``: write to a temporary file beside the target, fsync, ``os.replace``: an
  interrupted write leaves the previous file, never a truncated one.
"""
from __future__ import annotations

import io
import json
import os
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PolicyError", "atomic_write", "save_model", "save_normalization", "load_normalization",
           "vec_normalize", "load_model", "algo_of"]


class PolicyError(ValueError):
    """A policy file that is missing, corrupt, unsafe or does not fit the environment."""


def atomic_write(path: str | os.PathLike, write: Callable[[Any], Any]) -> None:
    """``write(f)`` into a binary temporary file beside ``path``, fsync it, then rename it
    over ``path`` (and fsync the folder)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:             # a folder that cannot be opened (some platforms): the rename stands
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def check_writable(out: str | os.PathLike, option: str = "--out") -> None:
    """Create the folder ``out`` and write a probe file in it, or raise ValueError naming
    ``option``: a command checks where its results go before any work."""
    import tempfile
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=out, prefix=".write-test-")
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise ValueError(f"{option} {str(out)!r} cannot be written ({e.strerror or e}); "
                         f"choose another folder") from None


def csv_text(rows: Any, columns: list[str]) -> str:
    """The CSV of ``rows`` (dicts; keys outside ``columns`` ignored), header first: for
    ``write_text``, so that a table is written whole or not at all."""
    import csv
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def write_text(path: str | os.PathLike, text: str) -> None:
    """``text`` to ``path`` whole or not at all (``atomic_write``), UTF-8; a character UTF-8
    cannot hold (a surrogate from a file name that is not UTF-8) written as its escape."""
    data = text.encode("utf-8", errors="backslashreplace")
    atomic_write(path, lambda f: f.write(data))


def save_figure(fig: Any, path: str | os.PathLike, dpi: int = 110) -> None:
    """A matplotlib figure to ``path`` whole or not at all (``atomic_write``), in the format
    its suffix names (PNG without one)."""
    fmt = Path(path).suffix[1:].lower() or "png"
    atomic_write(path, lambda f: fig.savefig(f, format=fmt, dpi=dpi))


def save_model(model: Any, path: str | os.PathLike) -> None:
    """``model.save`` atomically to ``path`` (a ``.zip``)."""
    atomic_write(path, model.save)


def drop_optimizer_state(path):
    """Rewrite the SB3 zip ``path`` with each optimizer's moments emptied (its ``state``; the
    hyperparameters in ``param_groups`` kept) and every other entry as it was: acting never
    reads them, fine-tuning restarts the optimizer, and the file is a third of the size. The
    weights are untouched (the same actions)."""
    import torch
    path = Path(path)
    with zipfile.ZipFile(path) as z:
        entries = [(info, z.read(info.filename)) for info in z.infolist()]

    def write(f):
        with zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED) as z:
            for info, raw in entries:
                if info.filename.endswith("optimizer.pth"):
                    sd = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
                    sd["state"] = {}
                    buf = io.BytesIO()
                    torch.save(sd, buf)
                    raw = buf.getvalue()
                z.writestr(info, raw, compress_type=zipfile.ZIP_DEFLATED)
    atomic_write(path, write)


_NORM_FLOATS = ("clip_obs", "clip_reward", "gamma", "epsilon")
_NORM_FLAGS = ("norm_obs", "norm_reward")


def save_normalization(vn: Any, path: str | os.PathLike) -> None:
    """The statistics of ``vn`` (a ``VecNormalize``) as plain arrays in ``path`` (``.npz``)."""
    arrays = {"obs_mean": vn.obs_rms.mean, "obs_var": vn.obs_rms.var, "obs_count": vn.obs_rms.count,
              "ret_mean": vn.ret_rms.mean, "ret_var": vn.ret_rms.var, "ret_count": vn.ret_rms.count}
    arrays.update({k: float(getattr(vn, k)) for k in _NORM_FLOATS})
    arrays.update({k: bool(getattr(vn, k)) for k in _NORM_FLAGS})
    arrays = {k: np.asarray(v, dtype=bool if k in _NORM_FLAGS else np.float64) for k, v in arrays.items()}
    atomic_write(path, lambda f: np.savez(f, **arrays))


def load_normalization(path: str | os.PathLike) -> dict[str, Any]:
    """The statistics saved by ``save_normalization``: a dict of float64 arrays (``obs_*``,
    ``ret_*``), floats and bools. ``PolicyError`` for a file that is not such an ``.npz``."""
    path = Path(path)
    if not path.is_file():
        raise PolicyError(f"normalisation statistics {path} do not exist")
    try:
        with np.load(path, allow_pickle=False) as d:
            out = {k: np.array(d[k]) for k in d.files}
    except Exception as e:          # truncated, not a zip, pickled object arrays
        raise PolicyError(f"normalisation statistics {path} are corrupt or not plain arrays: {e}") from None
    need = ("obs_mean", "obs_var", "obs_count", "ret_mean", "ret_var", "ret_count") + _NORM_FLOATS + _NORM_FLAGS
    missing = [k for k in need if k not in out]
    if missing:
        raise PolicyError(f"normalisation statistics {path} lack {', '.join(missing)}")
    for k in need:
        if out[k].dtype.kind not in ("b" if k in _NORM_FLAGS else "fiu"):
            raise PolicyError(f"normalisation statistics {path}: {k} has dtype {out[k].dtype}")
    for k in ("obs", "ret"):
        mean, var, count = out[f"{k}_mean"], out[f"{k}_var"], out[f"{k}_count"]
        if mean.shape != var.shape or count.shape != () or not (np.isfinite(mean).all() and np.isfinite(var).all()
                                                                and (var >= 0).all() and np.isfinite(count)
                                                                and count > 0):
            raise PolicyError(f"normalisation statistics {path}: {k}_mean/var/count must be finite, "
                              f"var >= 0, count > 0 and the shapes match")
    res = {k: out[k].astype(np.float64) for k in need if k.startswith(("obs_", "ret_"))}
    res.update({k: float(out[k]) for k in _NORM_FLOATS})
    res.update({k: bool(out[k]) for k in _NORM_FLAGS})
    if not (res["clip_obs"] > 0 and res["clip_reward"] > 0 and 0 < res["gamma"] <= 1 and res["epsilon"] > 0):
        raise PolicyError(f"normalisation statistics {path}: clip_obs, clip_reward, epsilon must be > 0 "
                          f"and gamma in (0, 1]")
    return res


#: a replay buffer's arrays saved (SB3's ReplayBuffer without optimize_memory_usage)
_REPLAY_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def save_replay(buffer: Any, path: str | os.PathLike) -> None:
    """The filled part of ``buffer`` (an SB3 ``ReplayBuffer``) as plain arrays in ``path``
    (``.npz``, atomic): SB3's own ``save_replay_buffer`` pickles, which no file of ours may need
    to be read back."""
    n = buffer.buffer_size if buffer.full else buffer.pos
    arrays = {k: getattr(buffer, k)[:n] for k in _REPLAY_ARRAYS}
    arrays.update(pos=np.int64(buffer.pos), full=np.bool_(buffer.full))
    atomic_write(path, lambda f: np.savez(f, **arrays))


def load_replay(buffer: Any, path: str | os.PathLike) -> int:
    """Fill ``buffer`` (a new SB3 ``ReplayBuffer`` of the run's sizes) from ``save_replay``'s
    file; returns the transitions loaded. ``PolicyError`` (the buffer untouched) for a file
    that is not such an ``.npz`` or does not fit the buffer."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as d:
            out = {k: np.array(d[k]) for k in d.files}
    except Exception as e:          # missing, truncated, not a zip, pickled object arrays
        raise PolicyError(f"replay buffer {path} is missing, corrupt or not plain arrays: {e}") from None
    missing = [k for k in _REPLAY_ARRAYS + ("pos", "full") if k not in out]
    if missing:
        raise PolicyError(f"replay buffer {path} lacks {', '.join(missing)}")
    pos, full = out["pos"], out["full"]
    if pos.shape != () or pos.dtype.kind not in "iu" or full.shape != () or full.dtype.kind != "b" \
            or not 0 <= int(pos) < buffer.buffer_size:
        raise PolicyError(f"replay buffer {path}: pos {pos!r} / full {full!r} do not fit a buffer of "
                          f"{buffer.buffer_size}")
    pos, full = int(pos), bool(full)
    n = buffer.buffer_size if full else pos
    for k in _REPLAY_ARRAYS:
        mine = getattr(buffer, k)
        if out[k].shape != (n,) + mine.shape[1:] or out[k].dtype != mine.dtype or not np.isfinite(out[k]).all():
            raise PolicyError(f"replay buffer {path}: {k} has shape {out[k].shape} and dtype {out[k].dtype} (or "
                              f"non-finite values); this run's is ({n}, {', '.join(map(str, mine.shape[1:]))}) "
                              f"{mine.dtype}")
    for k in _REPLAY_ARRAYS:
        getattr(buffer, k)[:n] = out[k]
    buffer.pos, buffer.full = pos, full
    return n * buffer.n_envs


def vec_normalize(stats: dict[str, Any], venv: Any, training: bool) -> Any:
    """A ``VecNormalize`` around ``venv`` with the statistics ``stats`` (``load_normalization``)."""
    from stable_baselines3.common.vec_env import VecNormalize
    vn = VecNormalize(venv, training=training, norm_obs=stats["norm_obs"], norm_reward=stats["norm_reward"],
                      clip_obs=stats["clip_obs"], clip_reward=stats["clip_reward"], gamma=stats["gamma"],
                      epsilon=stats["epsilon"])
    if tuple(stats["obs_mean"].shape) != tuple(vn.obs_rms.mean.shape):
        raise PolicyError(f"normalisation statistics for observations of shape {stats['obs_mean'].shape}; "
                          f"the environment gives {vn.obs_rms.mean.shape}")
    vn.obs_rms.mean, vn.obs_rms.var, vn.obs_rms.count = stats["obs_mean"].copy(), stats["obs_var"].copy(), \
        float(stats["obs_count"])
    vn.ret_rms.mean, vn.ret_rms.var, vn.ret_rms.count = stats["ret_mean"].copy(), stats["ret_var"].copy(), \
        float(stats["ret_count"])
    return vn


def _floats(text):
    """The numbers of a printed 1-d numpy array such as ``'[-1. -1. 20.]'``."""
    body = text.strip()
    if not (body.startswith("[") and body.endswith("]")):
        raise ValueError(f"not a printed array: {text[:40]!r}")
    return np.array([float(x) for x in body[1:-1].split()], dtype=np.float64)


def _box(key, entry):
    from gymnasium import spaces
    if "gymnasium.spaces.box.Box" not in str(entry.get(":type:")):
        raise ValueError(f"{key} is a {entry.get(':type:')}, only Box spaces are read")
    shape = tuple(int(n) for n in entry["_shape"])
    dtype = np.dtype(str(entry["dtype"]))
    if dtype.kind != "f":
        raise ValueError(f"{key} has dtype {dtype}")
    low, high = _floats(entry["low"]), _floats(entry["high"])
    if len(shape) != 1 or low.shape != shape or high.shape != shape:
        raise ValueError(f"{key} must be a 1-d Box with printed bounds, shape {shape}")
    return spaces.Box(low.astype(dtype), high.astype(dtype), shape=shape, dtype=dtype)


def _constant(key, entry):
    m = re.fullmatch(r"ConstantSchedule\(val=([-+0-9.eE]+)\)", str(entry.get("value_schedule", "")))
    if m is None:
        raise ValueError(f"{key} is not a constant schedule")
    return float(m.group(1))


def algo_of(data: dict[str, Any]) -> str:
    """'sac' or 'ppo' from a zip's ``data`` entries (SAC has a replay buffer)."""
    return "sac" if "buffer_size" in data else "ppo"


def _safe_objects(data, algo, extra):
    """``custom_objects`` for SB3's ``load`` that stand in for every pickled entry of ``data``."""
    from stable_baselines3 import PPO, SAC
    cls = {"ppo": PPO, "sac": SAC}[algo]
    dropped = {"_last_obs", "_last_episode_starts", "_last_original_obs", "ep_info_buffer", "ep_success_buffer",
               "rollout_buffer_class", "replay_buffer_class", "action_noise"}     # SB3 recreates them
    objs = {}
    for key, entry in data.items():
        if not (isinstance(entry, dict) and ":serialized:" in entry):
            continue
        if key in extra:
            objs[key] = extra[key]
        elif key in dropped:
            objs[key] = None
        elif key == "policy_class":
            objs[key] = cls.policy_aliases["MlpPolicy"]
        elif key in ("observation_space", "action_space"):
            objs[key] = _box(key, entry)
        elif key in ("lr_schedule", "clip_range", "clip_range_vf", "learning_rate"):
            objs[key] = _constant(key, entry)
        elif key == "train_freq":
            objs[key] = 1           # acting does not use it; training passes its own in extra
        else:
            raise ValueError(f"entry {key!r} is pickled ({entry.get(':type:')}) and is not read")
    if "lr_schedule" in objs:       # SB3 rebuilds it from learning_rate; a callable is expected
        v = objs["lr_schedule"]
        objs["lr_schedule"] = lambda _progress: v
    return cls, objs


def load_model(zip_path: str | os.PathLike, env: Any = None, algo: str | None = None,
               extra: dict[str, Any] | None = None) -> Any:
    """An SB3 PPO/SAC model from ``zip_path`` with no pickled entry read (module docstring).
    ``extra``: replacements for entries (e.g. ``{"train_freq": 8}`` to continue training a SAC
    model). ``PolicyError`` for a missing, corrupt or unsafe file."""
    import torch
    zip_path = Path(zip_path)
    try:
        with zipfile.ZipFile(zip_path) as z:
            data = json.loads(z.read("data").decode())
            for name in z.namelist():
                if name.endswith(".pth"):
                    torch.load(io.BytesIO(z.read(name)), map_location="cpu", weights_only=True)
    except Exception as e:          # not a zip, truncated, no data entry, a .pth beyond tensors
        raise PolicyError(f"policy file {zip_path} is corrupt or not a plain SB3 model: {e}") from None
    if not isinstance(data, dict):
        raise PolicyError(f"policy file {zip_path}: its data entry is not a JSON object")
    algo = algo or algo_of(data)
    try:
        cls, objs = _safe_objects(data, algo, dict(extra or {}))
    except (ValueError, KeyError, TypeError) as e:
        raise PolicyError(f"policy file {zip_path} refused: {e}") from None
    try:
        return cls.load(str(zip_path), env=env, device="cpu", custom_objects=objs)
    except Exception as e:
        raise PolicyError(f"policy file {zip_path} is corrupt or not an SB3 {algo.upper()} model: {e}") from None
