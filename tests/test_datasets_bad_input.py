"""fusion.datasets on bad input: every error names the file (or folder), the key and what is
expected, instead of a raw numpy traceback."""
import io
import zipfile

import numpy as np
import pytest

from fusion import datasets


def _arrays(n=20, fs=100.0):
    return dict(t=np.arange(n) / fs, gyr=np.zeros((n, 3)), acc=np.tile([0.0, 0.0, 9.81], (n, 1)),
                mag=np.tile([0.0, 0.4, -0.3], (n, 1)), quat=np.tile([1.0, 0, 0, 0], (n, 1)),
                fs=np.float64(fs), quality=np.str_("ok"), notes=np.str_("test"))


def _write(path, **arrays):
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return path


def test_good_file_loads(tmp_path):
    # the baseline the bad cases below differ from by one thing each
    tr = datasets.load_trial(_write(tmp_path / "s" / "good.npz", **_arrays()))
    assert tr.n == 20 and tr.has_mag and tr.ok


@pytest.mark.parametrize("key", datasets.REQUIRED)
def test_missing_required_key_names_file_key_and_expectation(tmp_path, key):
    a = _arrays()
    del a[key]
    p = _write(tmp_path / "s" / f"no_{key}.npz", **a)
    with pytest.raises(ValueError) as exc:
        datasets.load_trial(p)
    msg = str(exc.value)
    assert str(p) in msg
    assert f"'{key}'" in msg
    assert datasets.EXPECTED[key] in msg          # what the key must hold
    assert "missing" in msg


def test_missing_key_also_from_load_folder(tmp_path):
    a = _arrays()
    del a["gyr"]
    p = _write(tmp_path / "s" / "b.npz", **a)
    _write(tmp_path / "s" / "a.npz", **_arrays())
    with pytest.raises(ValueError, match="'gyr'") as exc:
        datasets.load_folder(tmp_path)
    assert str(p) in str(exc.value)


def test_optional_mag_missing_is_fine(tmp_path):
    a = _arrays()
    del a["mag"]
    assert datasets.load_trial(_write(tmp_path / "s" / "six.npz", **a)).mag is None


@pytest.mark.parametrize("key, bad, expect", [
    ("gyr", np.zeros((20, 2)), r"'gyr' must have shape \(20, 3\)"),
    ("quat", np.zeros((19, 4)), r"'quat' must have shape \(20, 4\)"),
    ("t", np.zeros((20, 1)), r"'t' must have shape \(N,\)"),
    ("fs", np.array([100.0, 100.0]), r"'fs' must be a scalar"),
    ("acc", np.full((20, 3), "x"), r"'acc' must be numeric"),
    ("t", np.r_[np.arange(19) / 100.0, np.inf], r"'t' must be finite seconds \(row 19 is inf\)"),
    ("t", np.r_[np.nan, np.arange(1, 20) / 100.0], r"'t' must be finite seconds \(row 0 is nan\)"),
])
def test_bad_shape_or_type_names_file_and_key(tmp_path, key, bad, expect):
    a = _arrays()
    a[key] = bad
    p = _write(tmp_path / "s" / f"bad_{key}.npz", **a)
    with pytest.raises(ValueError, match=expect) as exc:
        datasets.load_trial(p)
    assert str(p) in str(exc.value)


@pytest.mark.parametrize("key, bad", [
    ("t", (np.arange(20) * 10).astype("m8[ms]")),          # cast to float: 10 "s" steps
    ("t", np.datetime64("2024-01-01T00:00:00.000") + (np.arange(20) * 10).astype("m8[ms]")),
    ("fs", np.array(True)),
    ("fs", np.array("100")),
    ("gyr", np.full((20, 3), "1.5")),                      # would cast to 1.5 without a word
    ("acc", np.ones((20, 3), dtype=bool)),
])
def test_dates_bools_and_strings_are_refused(tmp_path, key, bad):
    a = _arrays()
    a[key] = bad
    p = _write(tmp_path / "s" / f"dtype_{key}.npz", **a)
    with pytest.raises(ValueError, match=rf"'{key}' must be numeric \(int or float\)") as exc:
        datasets.load_trial(p)
    msg = str(exc.value)
    assert str(p) in msg and datasets.EXPECTED[key] in msg and str(bad.dtype) in msg
    if bad.dtype.kind in "mM":
        assert "float seconds" in msg


def test_pickled_object_array_is_a_clear_error(tmp_path):
    a = _arrays()
    a["extra"] = np.array([{"a": 1}], dtype=object)     # np.load refuses it without allow_pickle
    p = _write(tmp_path / "s" / "obj.npz", **a)
    with pytest.raises(ValueError, match="'extra' cannot be read") as exc:
        datasets.load_trial(p)
    assert str(p) in str(exc.value)


@pytest.mark.parametrize("content", [b"not a numpy file at all", b"PK\x03\x04 truncated zip"])
def test_unreadable_file_names_the_file(tmp_path, content):
    p = tmp_path / "s" / "junk.npz"
    p.parent.mkdir()
    p.write_bytes(content)
    with pytest.raises(ValueError, match="not a readable .npz trial") as exc:
        datasets.load_trial(p)
    assert str(p) in str(exc.value)


def test_single_array_npy_is_rejected(tmp_path):
    p = tmp_path / "one.npy"
    np.save(p, np.zeros(3))
    with pytest.raises(ValueError, match="expected an .npz archive"):
        datasets.load_trial(p)


def test_missing_trial_file(tmp_path):
    p = tmp_path / "nope.npz"
    with pytest.raises(FileNotFoundError, match="does not exist") as exc:
        datasets.load_trial(p)
    assert str(p) in str(exc.value)


def test_missing_folder_names_the_path(tmp_path):
    missing = tmp_path / "no" / "such" / "folder"
    with pytest.raises(ValueError, match="does not exist") as exc:
        datasets.load_folder(missing)
    assert str(missing) in str(exc.value)


def test_file_given_as_folder(tmp_path):
    p = _write(tmp_path / "s" / "good.npz", **_arrays())
    with pytest.raises(ValueError, match="is not a folder") as exc:
        datasets.load_folder(p)
    assert str(p) in str(exc.value)


def _corrupt_member(path, member="gyr.npy"):
    """Flip one byte in the middle of ``member``'s stored data (the zip directory stays valid)."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    raw = bytearray(path.read_bytes())
    raw[info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2] ^= 0xFF
    path.write_bytes(bytes(raw))


def _raw_member(path, key):
    """The trial with ``key`` stored as raw bytes, without the ``.npy`` format (NpzFile gives bytes)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w") as z:
        for k, v in _arrays().items():
            if k == key:
                z.writestr(k, b"ok")
            else:
                buf = io.BytesIO()
                np.save(buf, v)
                z.writestr(f"{k}.npy", buf.getvalue())
    return path


@pytest.mark.parametrize("save", [np.savez, np.savez_compressed])
def test_corrupt_member_is_a_value_error(tmp_path, save):
    p = tmp_path / "s" / "crc.npz"
    p.parent.mkdir()
    save(p, **_arrays(n=2000))
    _corrupt_member(p)
    with pytest.raises(ValueError, match="member 'gyr.npy' is corrupt") as exc:
        datasets.load_trial(p)                   # was: zipfile.BadZipFile
    assert str(p) in str(exc.value)


@pytest.mark.parametrize("local, central, value, expect", [
    (8, 10, 99, "compression method"),           # an unknown compression method: NotImplementedError
    (6, 8, 1, "encrypted"),                      # the encryption flag: RuntimeError
])
def test_unsupported_member_is_a_value_error(tmp_path, local, central, value, expect):
    p = _write(tmp_path / "s" / "odd.npz", **_arrays())
    with zipfile.ZipFile(p) as z:
        first = z.infolist()[0]
    raw = bytearray(p.read_bytes())
    raw[first.header_offset + local] |= value                   # the local header's field
    raw[raw.find(b"PK\x01\x02") + central] |= value             # and the central directory's
    p.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=f"not a readable .npz trial .*{expect}") as exc:
        datasets.load_trial(p)
    assert str(p) in str(exc.value)


@pytest.mark.parametrize("key", ["gyr", "quality"])
def test_member_without_npy_is_a_value_error(tmp_path, key):
    p = _raw_member(tmp_path / "s" / "raw.npz", key)
    with pytest.raises(ValueError, match=f"'{key}' cannot be read .*not a .npy array") as exc:
        datasets.load_trial(p)                   # was: AttributeError
    assert str(p) in str(exc.value)


def test_an_extra_member_without_npy_is_kept_as_it_is(tmp_path):
    """Members the loader does not know are kept in Trial.extra whatever they hold (a notes
    file beside the arrays); only the known keys must be .npy arrays."""
    p = _write(tmp_path / "s" / "extra.npz", **_arrays())
    with zipfile.ZipFile(p, "a") as z:
        z.writestr("notes.txt", b"recorded by hand")
    tr = datasets.load_trial(p)
    assert tr.extra["notes.txt"].item() == b"recorded by hand"


def test_load_folder_collects_corrupt_files(tmp_path):
    _write(tmp_path / "s" / "good.npz", **_arrays())
    _raw_member(tmp_path / "s" / "raw.npz", "quality")
    crc = tmp_path / "s" / "crc.npz"
    np.savez(crc, **_arrays(n=2000))
    _corrupt_member(crc)
    bad = []
    trials = datasets.load_folder(tmp_path, unreadable=bad)
    assert [tr.key for tr in trials] == ["s/good"]
    assert [k for k, _ in bad] == ["s/crc", "s/raw"]
    assert str(crc) in bad[0][1]


@pytest.mark.parametrize("t, fs, match", [
    (np.arange(200) * 10.0, 100.0, "must be in seconds"),                  # stamps in ms
    (np.arange(200) / 100.0, 1.0, "must be in seconds"),                   # fs not the stamps' rate
    ((np.arange(1500) / 100.0).astype(np.float16), 100.0, "store 't' as float64"),
])
def test_stamps_in_other_units_or_an_unresolving_dtype_are_refused(tmp_path, t, fs, match):
    """Stamps in ms (every step 1000x), an fs that is not the stamps' rate, or float16 stamps
    (8 ms apart at 15 s) gave every estimator wrong steps, silently."""
    a = _arrays(n=t.shape[0], fs=fs)
    a["t"] = t
    with pytest.raises(ValueError, match=match):
        datasets.load_trial(_write(tmp_path / "s" / "x.npz", **a))


def test_stamps_a_little_off_the_nominal_rate_load(tmp_path):
    a = _arrays(n=200)
    a["t"] = np.arange(200) / 104.0            # 4 % off, as a real set's clock
    assert datasets.load_trial(_write(tmp_path / "s" / "x.npz", **a)).n == 200


def test_two_trials_with_one_key_are_refused(tmp_path):
    _write(tmp_path / "a" / "set" / "x.npz", **_arrays())
    _write(tmp_path / "b" / "set" / "x.npz", **_arrays())
    with pytest.raises(ValueError, match="two trials have the key 'set/x'"):
        datasets.load_folder(tmp_path)


def test_load_folder_arguments_are_checked(tmp_path):
    _write(tmp_path / "s" / "x.npz", **_arrays())
    with pytest.raises(ValueError, match="only_ok must be True or False"):
        datasets.load_folder(tmp_path, only_ok="no")
    with pytest.raises(ValueError, match="unreadable must be None or a list"):
        datasets.load_folder(tmp_path, unreadable=())
    with pytest.raises(ValueError, match="folder must be a folder path"):
        datasets.load_folder(None)
    with pytest.raises(ValueError, match="path must be a file path"):
        datasets.load_trial(None)
