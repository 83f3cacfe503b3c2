"""The one validator of numbers, integers, choices and flags given by users: fusion's
estimators (through `fusion.Param`), the IMU model, the environments and the controllers.
Each check returns the value in its canonical type or raises a ValueError that names the
argument, says what is accepted and shows what was given. Also the checks that an optional
extra is installed, for a command (`require`) and a library function (`require_import`)."""
import importlib.util
import math
import numbers
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["number", "integer", "choice", "flag", "interval", "state_header", "not_masked",
           "SAMPLES_HINT", "EXTRAS", "missing_extra", "require", "require_import"]


def interval(low: float | None, high: float | None, open_low: bool = False, open_high: bool = False) -> str:
    """'[low, high]' with '(' / ')' for open ends (None: unbounded)."""
    lo = "-inf" if low is None else f"{low:g}"
    hi = "inf" if high is None else f"{high:g}"
    return (("(" if open_low or low is None else "[") + f"{lo}, {hi}"
            + (")" if open_high or high is None else "]"))


def _accepted(low, high, open_low, open_high, allow_zero, allow_inf):
    finite = "finite (or inf)" if allow_inf else "finite"
    rng = interval(low, high, open_low, open_high)
    if low is None or low < 0:
        return f"{finite} and in {rng}" + (" or 0" if allow_zero else "")
    sign = ">= 0" if allow_zero or (low == 0 and not open_low) else "> 0"
    if low == 0 and high is None:
        return f"{finite} and {sign}"
    return f"{finite} and {sign} and in {rng}" + (" (or 0)" if allow_zero and low > 0 else "")


def number(name: str, value: Any, low: float | None = None, high: float | None = None, *,
           open_low: bool = False, open_high: bool = False, allow_zero: bool = False,
           allow_inf: bool = False, allow_none: bool = False, unit: str = "") -> float | None:
    """float(value) if it is a finite real number in [low, high] (an end None: unbounded;
    open_low / open_high: that end excluded), or 0 with allow_zero, or +inf with allow_inf,
    or None with allow_none. A 0-d real array (what indexing or reducing an array gives)
    counts as its number."""
    if value is None and allow_none:
        return None
    if isinstance(value, np.ndarray):       # a masked array is one: plain floats pay nothing
        not_masked(name, value)
        if value.ndim == 0 and value.dtype.kind in "fiu":
            value = value.item()
    # (np.timedelta64 registers as an integer, but float() and int() refuse it)
    if isinstance(value, (bool, np.bool_, np.timedelta64)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number{' or None' if allow_none else ''}, got {value!r}")
    v = float(value)
    ok = (math.isfinite(v) or (allow_inf and v == math.inf)) and (
        (allow_zero and v == 0.0)
        or ((low is None or (v > low if open_low else v >= low))
            and (high is None or v == math.inf or (v < high if open_high else v <= high))))
    if not ok:
        rng = _accepted(low, high, open_low, open_high, allow_zero, allow_inf)
        raise ValueError(f"{name} must be {rng}{unit}{' or None' if allow_none else ''}, got {value!r}")
    return v


def integer(name: str, value: Any, low: int | None = None, high: int | None = None, *,
            allow_none: bool = False, unit: str = "") -> int | None:
    """int(value) if it is an integer (not a bool) in [low, high] (None: unbounded)."""
    if value is None and allow_none:
        return None
    if (isinstance(value, (bool, np.bool_, np.timedelta64)) or not isinstance(value, numbers.Integral)
            or (low is not None and value < low) or (high is not None and value > high)):
        rng = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ValueError(f"{name} must be an integer {rng}{unit}{' or None' if allow_none else ''}, got {value!r}")
    return int(value)


# not_masked's hint where the value is sensor samples, which on_invalid handles
SAMPLES_HINT = ("np.ma.filled({name}, np.nan) makes the masked samples invalid ones, which on_invalid then "
                "refuses or skips")


def arg_type(check: Callable[..., Any], **bounds: Any) -> Callable[[str], Any]:
    """An argparse ``type``: the option's text as a number checked by ``check`` (``number`` or
    ``integer``) with ``bounds`` (their keywords), so that a command's bad value is argparse's
    one-line error saying what is accepted, before any work."""
    import argparse

    def parse(text: str) -> Any:
        v: Any = text
        try:
            v = float(text)
            if check is integer:        # exact for a long integer; 1e3 is 1000
                v = int(text) if text.strip().lstrip("+-").isdigit() else int(v) if v.is_integer() else text
        except (ValueError, OverflowError):
            pass
        try:
            return check("the value", v, **bounds)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
    return parse


def not_masked(name: str, value: Any, hint: str = "") -> None:
    """A ValueError if value is a numpy masked array: np.asarray would drop its mask and use
    the masked values as data. hint: what to do instead, formatted with name (SAMPLES_HINT)."""
    if isinstance(value, np.ma.MaskedArray):
        raise ValueError(f"{name} is a masked array, whose mask would be ignored: pass a plain array"
                         + (f" ({hint.format(name=name)})" if hint else ""))


def finite_vector(name: str, value: Any, n: int, message: str | None = None) -> np.ndarray:
    """value as n finite floats (shape (n,)), else ValueError(message, default "<name> must be
    n finite real numbers") with the value: a masked array, complex, bool, strings and a value
    beyond float64 (a longdouble) are refused, not cast."""
    msg = message or f"{name} must be {n} finite real numbers"
    not_masked(name, value)
    a = np.asarray(value)
    # (numpy reads (True, 30.0, -30.0) as floats: a bool among numbers is refused here)
    mixed_bool = isinstance(value, (list, tuple)) and any(isinstance(v, (bool, np.bool_)) for v in value)
    if a.shape != (n,) or a.dtype.kind not in "iuf" or mixed_bool:
        raise ValueError(f"{msg}, got {value!r}")
    a = a.astype(float)
    if not np.isfinite(a).all():
        raise ValueError(f"{msg}, got {value!r}")
    return a


def choice(name: str, value: Any, choices: tuple) -> Any:
    """value if it is one of choices (compared by type and value: "1" is not 1)."""
    if not any(type(value) is type(c) and value == c for c in choices):
        raise ValueError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def state_header(state: Any, keys: tuple, version: int, made_by: str) -> None:
    """A ValueError unless state is a dict with every key of keys whose "version" is version:
    a state saved in another format (made_by, e.g. "est.state()", wrote it) is refused by its
    version with what to do, before any field is read."""
    if not isinstance(state, dict):
        raise ValueError(f"state must be a dict made by {made_by}, got {type(state).__name__}")
    missing = [k for k in keys if k not in state]
    if missing:
        raise ValueError(f"state lacks key(s) {', '.join(missing)}; it must come from {made_by}")
    v = state["version"]
    if isinstance(v, bool) or not isinstance(v, int) or v != version:
        when = ("was saved by an older build" if isinstance(v, int) and not isinstance(v, bool) and v < version
                else "is not a version this build knows")
        raise ValueError(f"state version {v!r} {when}: this build reads version {version} only (its "
                         f"fields changed; a state is not converted): make it again with {made_by} "
                         f"of this build")


def flag(name: str, value: Any) -> bool:
    """value as a bool if it is True or False (numpy's too), else a ValueError."""
    if value is not True and value is not False and not isinstance(value, np.bool_):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


# pyproject.toml's extras that the commands need: extra -> (the extra it includes, the modules it
# adds, by import name); tests/test_packaging.py holds this to pyproject.toml
EXTRAS: dict[str, tuple[str | None, tuple[str, ...]]] = {
    "plot": (None, ("matplotlib", "tqdm")),
    "sim": ("plot", ("gymnasium", "pybullet", "scipy")),
    "rl": ("sim", ("stable_baselines3", "torch", "yaml", "rich")),
    "ray": (None, ("ray",)),
}


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None    # None too for a None in sys.modules
    except ValueError:                                          # loaded, without a __spec__
        return True


def missing_extra(what: str, extra: str) -> str | None:
    """None if every module of ``extra`` (and of the extras it includes) is importable, else
    the message: ``what`` needs the extra, the missing modules, the pip command."""
    gone, e = [], extra
    while e is not None:                  # the extra, then the one it includes
        e, modules = EXTRAS[e]
        gone += [m for m in modules if not _importable(m)]
    if not gone:
        return None
    return (f"{what} needs the {extra!r} extra ({', '.join(gone)} not installed): "
            f"pip install 'spherebot-fusion[{extra}]'")


def require(command: str, extra: str) -> None:
    """For a command's main() after its arguments are parsed, before any work: unless ``extra``
    is installed, print its message to stderr and exit with status 2, argparse's for a usage
    error (rather than a traceback halfway through the run)."""
    message = missing_extra(command, extra)
    if message:
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2)


def require_import(what: str, extra: str) -> None:
    """For a library function that needs ``extra``, before any work: unless it is installed,
    raise ModuleNotFoundError with its message (rather than "No module named 'torch'" from
    somewhere inside)."""
    message = missing_extra(what, extra)
    if message:
        raise ModuleNotFoundError(message)
