"""Readers for recorded IMU data with a reference orientation (numpy only).

The recorded sets live in ``<data folder>/<set>/<trial>.npz``, the folder given by
``$FUSION_DATA_DIR`` or else ``DEFAULT_DATA_DIR`` (declared once, below); the format is in the
folder's README, "Recorded IMU data with a reference orientation": ``t``, ``gyr``, ``acc``,
optional ``mag``, reference ``quat`` (Hamilton ``[w, x, y, z]``, IMU -> earth, z up, NaN
rows where the reference was lost), ``fs``,
``quality`` (``'ok'`` or a reason not to score the trial) and ``notes``. Any other arrays in
the file (e.g. ``q_align``, ``q_earth_fix``) are kept in ``Trial.extra``.

    import fusion
    from fusion import datasets
    root = datasets.default_data_dir()          # None where the folder is absent
    for trial in datasets.load_folder(root):
        if trial.ok:
            est = fusion.make("ekf-lp", trial.fs)
            q = est.run(trial.gyr, trial.acc, trial.mag, dt=trial.dt)
"""
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fusion.checks import flag

__all__ = ["Trial", "load_trial", "load_folder", "default_data_dir", "ENV_VAR", "DEFAULT_DATA_DIR", "DATA_LOCATION",
           "EXPECTED", "REQUIRED"]

# where the recorded data is: the one declaration, used by the scripts, benchmarks and tests
ENV_VAR = "FUSION_DATA_DIR"
#: the folder when $FUSION_DATA_DIR is not set: ``shared/data`` beside the repository's folder
DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2] / "shared" / "data"
#: how messages and --help name it
DATA_LOCATION = f"${ENV_VAR}, else {DEFAULT_DATA_DIR}"
_KNOWN = ("t", "gyr", "acc", "mag", "quat", "fs", "quality", "notes")
# what each array key must hold: the error messages quote it
EXPECTED = {"t": "(N,) time in s, increasing", "gyr": "(N, 3) angular rate in rad/s",
            "acc": "(N, 3) specific force in m/s^2", "mag": "(N, 3) magnetometer (optional)",
            "quat": "(N, 4) reference quaternion [w, x, y, z], IMU -> earth",
            "fs": "a scalar: nominal sample rate in Hz"}
REQUIRED = ("t", "gyr", "acc", "quat", "fs")


@dataclass(eq=False)
class Trial:
    """One recorded trial in memory. Arrays have N rows; ``mag`` is None for 6-axis devices.

    ``dt`` is the step into each sample from the time stamps, ``dt[i] = t[i] - t[i-1]``, and
    ``dt[0] = 1/fs`` (the step the estimators' ``run(..., dt=trial.dt)`` expects).
    """
    name: str
    set: str
    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray | None
    quat: np.ndarray
    fs: float
    quality: str
    notes: str
    dt: np.ndarray
    path: Path | None = None
    extra: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when the trial may be scored (``quality == 'ok'``)."""
        return self.quality.strip().lower() == "ok"

    @property
    def has_mag(self) -> bool:
        return self.mag is not None

    @property
    def n(self) -> int:
        return self.t.shape[0]

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if self.n else 0.0

    @property
    def key(self) -> str:
        """``"<set>/<name>"``, unique within a data folder."""
        return f"{self.set}/{self.name}"

    def __repr__(self):
        return (f"Trial({self.key!r}, n={self.n}, fs={self.fs:.2f}, "
                f"mag={'yes' if self.has_mag else 'no'}, quality={self.quality!r})")


def _get(d, key, path, raw_ok=False):
    """``d[key]``; ValueError naming the file and key for what numpy will not load (a pickled
    object array under allow_pickle=False) or, unless raw_ok (the extras, kept as they are),
    loads as raw bytes (a member stored without ``.npy``, which ``NpzFile`` hands back
    unparsed)."""
    try:
        arr = d[key]
    except ValueError as e:
        raise ValueError(f"{path}: key {key!r} cannot be read ({e})") from None
    if not raw_ok and not isinstance(arr, np.ndarray):
        raise ValueError(f"{path}: key {key!r} cannot be read (not a .npy array but {type(arr).__name__})")
    return arr


def _float(d, key, path):
    """``d[key]`` as a float array; ValueError naming the file and key where it is not
    int or float: the cast would silently change the meaning of the other dtypes (a complex
    array loses its imaginary part, a timedelta64 't' becomes counts of its own unit, bool
    and strings become numbers)."""
    return _as_float(_get(d, key, path), key, path)


def _as_float(arr, key, path):
    """``_float`` of an array already read."""
    if np.iscomplexobj(arr):
        raise ValueError(f"{path}: {key!r} must be real, {EXPECTED[key]} (got complex dtype {arr.dtype})")
    if arr.dtype.kind not in "iuf":
        hint = "; store times as float seconds" if arr.dtype.kind in "mM" else ""
        raise ValueError(f"{path}: {key!r} must be numeric (int or float), {EXPECTED[key]} "
                         f"(got dtype {arr.dtype}{hint})")
    return np.asarray(arr, dtype=float)


def _text(d, key, path):
    """A scalar string array (str or bytes, decoded as UTF-8) as a str: ``str()`` of a bytes
    array would give "b'ok'", and the trial would silently not be 'ok'."""
    arr = _get(d, key, path)
    if arr.dtype.kind not in "US" or arr.size != 1:
        raise ValueError(f"{path}: {key!r} must be a single string, got dtype {arr.dtype} shape {arr.shape}")
    v = arr.reshape(()).item()
    if isinstance(v, bytes):
        try:
            v = v.decode("utf-8")
        except UnicodeDecodeError as e:
            raise ValueError(f"{path}: {key!r} is bytes that are not UTF-8 ({e})") from None
    return str(v)


def _rows(d, n, cols, key, path):
    arr = _float(d, key, path)
    if arr.shape != (n, cols):
        raise ValueError(f"{path}: {key!r} must have shape ({n}, {cols}), got {arr.shape} "
                         f"(expected {EXPECTED[key]})")
    return arr


def _steps(t_raw, t, fs, path):
    """The sample steps ``dt`` (the first 1 / fs) of the stamps ``t`` (``t_raw`` as stored),
    with the checks of ``fs`` and the stamps (``load_trial``)."""
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"{path}: 'fs' must be a positive sample rate, got {fs}")
    if not np.isfinite(t).all():        # a last stamp of inf passed the increase test below
        raise ValueError(f"{path}: time stamps 't' must be finite seconds "
                         f"(row {int(np.argmax(~np.isfinite(t)))} is {t[~np.isfinite(t)][0]})")
    n = t.shape[0]
    dt = np.empty(n)
    if n:
        dt[0] = 1.0 / fs
        dt[1:] = np.diff(t)
        if n > 1 and not (dt[1:] > 0).all():
            raise ValueError(f"{path}: time stamps 't' must increase strictly "
                             f"(first bad step at row {int(np.argmax(dt[1:] <= 0)) + 1})")
    if n > 2:
        _check_stamps(t_raw, t, dt[1:], fs, path)
    return dt


def _check_stamps(t_raw, t, steps, fs, path):
    """The stamps are seconds at about the rate ``fs`` (their median step within a factor of 2
    of 1 / fs: stamps in ms, or an ``fs`` that is not the stamps' rate, would give every
    estimator wrong steps), in a dtype that resolves the steps (float16 at 15 s is 8 ms apart)."""
    step = float(np.median(steps))
    if not 0.5 <= step * fs <= 2.0:
        raise ValueError(f"{path}: the time stamps 't' step by {step:g} (median) but 'fs' is {fs:g} Hz, "
                         f"a step of {1.0 / fs:g} s: 't' must be in seconds and 'fs' the stamps' rate "
                         f"(within a factor of 2)")
    if t_raw.dtype.kind == "f":
        spacing = float(np.spacing(np.abs(t_raw).max()))
        if spacing > 0.01 * step:
            raise ValueError(f"{path}: 't' is {t_raw.dtype}, which is {spacing:g} s apart at "
                             f"{float(np.abs(t).max()):g} s, over 1 % of the {step:g} s steps: store 't' "
                             f"as float64 seconds")


def load_trial(path: str | os.PathLike) -> Trial:
    """Read one ``.npz`` trial into a ``Trial``. FileNotFoundError for a missing file;
    ValueError naming the file, the key and what it must hold for a missing key, a bad shape
    or a non-numeric array, for a file numpy cannot read as ``.npz`` (not a zip, a member
    that fails its CRC or is not ``.npy``), and for time stamps that are not finite, strictly
    increasing seconds at about ``fs`` (their median step within a factor of 2 of ``1 / fs``)
    in a dtype that resolves the steps (float16 does not)."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a file path (str or os.PathLike), got {type(path).__name__}")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trial file {str(path)!r} does not exist")
    try:
        d = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:   # not a file numpy can read
        raise ValueError(f"{path}: not a readable .npz trial ({e})") from None
    if not isinstance(d, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: expected an .npz archive of named arrays, got a single array")
    with d:
        # every member's CRC first: numpy would parse a corrupt header into any kind of error
        try:
            corrupt = d.zip.testzip()
        except (OSError, EOFError, zlib.error, NotImplementedError, RuntimeError) as e:   # RuntimeError: encrypted
            raise ValueError(f"{path}: not a readable .npz trial ({e})") from None
        if corrupt is not None:
            raise ValueError(f"{path}: not a readable .npz trial (member {corrupt!r} is corrupt: bad CRC)")
        missing = [k for k in REQUIRED if k not in d.files]
        if missing:
            want = "; ".join(f"{k!r}: {EXPECTED[k]}" for k in missing)
            raise ValueError(f"{path}: missing key(s) {missing}, required (expected {want}); "
                             f"the file has {sorted(d.files)}")
        t_raw = _get(d, "t", path)
        t = _as_float(t_raw, "t", path)
        if t.ndim != 1:
            raise ValueError(f"{path}: 't' must have shape (N,), got {t.shape} (expected {EXPECTED['t']})")
        n = t.shape[0]
        gyr = _rows(d, n, 3, "gyr", path)
        acc = _rows(d, n, 3, "acc", path)
        mag = _rows(d, n, 3, "mag", path) if "mag" in d.files else None
        q = _rows(d, n, 4, "quat", path)
        fs = _float(d, "fs", path)
        if fs.size != 1:
            raise ValueError(f"{path}: 'fs' must be {EXPECTED['fs']}, got shape {fs.shape}")
        fs = float(fs.reshape(()))
        quality = _text(d, "quality", path) if "quality" in d.files else "ok"
        notes = _text(d, "notes", path) if "notes" in d.files else ""
        extra = {k: np.asarray(_get(d, k, path, raw_ok=True)) for k in d.files if k not in _KNOWN}
    dt = _steps(t_raw, t, fs, path)
    return Trial(name=path.stem, set=path.parent.name, t=t, gyr=gyr, acc=acc, mag=mag, quat=q,
                 fs=fs, quality=quality, notes=notes, dt=dt, path=path, extra=extra)


def load_folder(folder: str | os.PathLike, only_ok: bool = False,
                unreadable: list[tuple[str, str]] | None = None) -> list[Trial]:
    """Every ``*.npz`` trial in ``folder`` and its sub-folders (a set folder, or the data root
    with one sub-folder per set), sorted by set and name. ``only_ok`` drops trials whose
    quality is not 'ok'. ValueError with the path when ``folder`` does not exist or is not a
    folder; ``load_trial``'s errors for a bad file, unless ``unreadable`` is a list: then each
    bad file is skipped and ``("<set>/<name>", message)`` appended to it. Trial keys
    (``<set>/<name>``) must be unique: two files with one key (``a/set/x.npz`` and
    ``b/set/x.npz``) are a ValueError naming both."""
    if not isinstance(folder, (str, os.PathLike)):
        raise ValueError(f"folder must be a folder path (str or os.PathLike), got {type(folder).__name__}")
    only_ok = flag("only_ok", only_ok)
    if unreadable is not None and not isinstance(unreadable, list):
        raise ValueError(f"unreadable must be None or a list to append (key, message) pairs to, "
                         f"got {type(unreadable).__name__}")
    folder = Path(folder)
    if not folder.exists():
        raise ValueError(f"data folder {str(folder)!r} does not exist")
    if not folder.is_dir():
        raise ValueError(f"data folder {str(folder)!r} is not a folder")
    trials = []
    for p in sorted(q for q in folder.rglob("*.npz") if q.is_file()):      # (a folder named x.npz is no trial)
        try:
            trials.append(load_trial(p))
        except (ValueError, OSError) as e:
            if unreadable is None:
                raise
            unreadable.append((f"{p.parent.name}/{p.stem}", str(e)))
    trials.sort(key=lambda tr: (tr.set, tr.name))
    for a, b in zip(trials, trials[1:]):
        if a.key == b.key:
            raise ValueError(f"two trials have the key {a.key!r} (the set folder's name and the file's): "
                             f"{a.path} and {b.path}; rename one, or load the folders one at a time")
    return [tr for tr in trials if tr.ok] if only_ok else trials


def default_data_dir() -> Path | None:
    """The recorded-data folder: ``$FUSION_DATA_DIR`` if set, else ``DEFAULT_DATA_DIR``. None
    when that folder does not exist (e.g. for an installed package without the data)."""
    env = os.environ.get(ENV_VAR)
    path = Path(env).expanduser() if env else DEFAULT_DATA_DIR
    return path if path.is_dir() else None
