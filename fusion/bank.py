"""A bank of count independent estimators of one kind in one object (docs/estimators.md,
"Banks"): many IMUs, or many robots, stepped by one call per sample.

    bank = fusion.make_bank("ekf", fs=100.0, count=64, acc_noise=[0.5] * 32 + [2.0] * 32)
    q = bank.update(gyr, acc, mag)      # (64, 3) each -> (64, 4)
    Q = bank.run(G, A, M)               # (T, 64, 3) each -> (T, 64, 4)

The loop over the filters is compiled and runs without the GIL (fusion._bank). A bank of
`ekf` (the class itself, acc_update="vector" and mag_update="heading" on every filter: the
defaults; any other numeric parameters, per filter or shared) keeps its filters' state in
structure-of-arrays layout and steps them four at a time (fusion/_ekfbank.h): the scalar
kernel's arithmetic on four filters per vector, equal to count separate estimators to 1e-12,
to 1e-9 after a time gap of 1 s or more (not bit for bit: the compiler fuses multiply-adds
differently, and a gap's large variance amplifies that; docs/estimators.md, "Banks"). A sample that is not the
usual one for a filter (not initialised, invalid, saturated, a time gap, a detector or the
low-pass starting) goes through that filter's own estimator object. Every other bank (other
estimators, other ekf configurations, iir-ekf) is an array of pointers to count kernels, each
stepped through its own batch loop: the numbers of count separate estimators, bit for bit.
"""
from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from fusion._bank import BankCore, as_samples, check_samples, time_steps
from fusion._core import Estimator, check_dt, unit_q0
from fusion.checks import integer, not_masked, state_header

BANK_STATE_VERSION = 1
BANK_STATE_KEYS = ("version", "bank", "estimator", "count", "filters")
# filters in one bank: building one takes 0.1-0.6 ms and a few kB (ekf to cf-ekf), so the
# largest bank takes 10-60 s; a count beyond it is a mistake (10**12 would build for years)
COUNT_MAX = 100_000


def _per_filter(value):
    """True for a parameter value given per filter: a list, tuple or array of one or more
    dimensions (a string is one value)."""
    return isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray) and value.ndim >= 1)


def make_bank(name: str, fs: float, count: int, frame: str = "ENU", on_invalid: str = "raise",
              **params: Any) -> Bank:
    """count independent estimators `name` at sample rate fs (Hz), as fusion.Bank.

    A parameter given as a sequence of length count gives each filter its own value; any
    other value is shared. frame and on_invalid are the bank's (fusion.make's meanings)."""
    import fusion
    count = integer("count", count, 1, COUNT_MAX)
    per = {k: v for k, v in params.items() if _per_filter(v)}
    for k, v in per.items():
        if isinstance(v, np.ndarray) and v.ndim != 1:
            raise ValueError(f"parameter {k} must be one value for all filters or a sequence of count = "
                             f"{count} values, got an array of shape {v.shape}")
        if len(v) != count:
            raise ValueError(f"parameter {k} has {len(v)} values but count is {count}: give one "
                             f"value for all filters or a sequence of length {count}")
        # (an array's elements as Python values: numpy scalars' .item(), an object array's as they are)
        per[k] = v.tolist() if isinstance(v, np.ndarray) else v
    filters = []
    for i in range(count):
        p = dict(params)
        p.update({k: v[i] for k, v in per.items()})
        try:
            filters.append(fusion.make(name, fs, frame=frame, on_invalid=on_invalid, **p))
        except ValueError as e:
            if per:
                raise ValueError(f"{e} (filter {i})") from None
            raise
    return Bank._own(filters)


def _shared(attr, doc):
    """A read-only property every filter of a bank has alike (read from the first)."""
    return property(lambda self: getattr(self._filters[0], attr), doc=doc)


def _stacked(attr, doc):
    """A read-only property: every filter's ``attr`` stacked into one array (``Bank._stack``)."""
    return property(lambda self: self._stack(attr), doc=doc)


class Bank(BankCore):
    """count estimators of one kind, same fs, frame and on_invalid, each with its own
    parameters and state. Build with fusion.make_bank, Bank(estimators) (copies them) or
    Bank.from_state; bank[i] is a copy of filter i."""

    def __init__(self, filters: Sequence[Estimator]) -> None:
        """A bank of copies of the given estimators (one kind, same fs, frame, on_invalid):
        the bank steps objects no one else holds, so its in-use guard covers them."""
        self._setup([Estimator.from_state(e.state()) if isinstance(e, Estimator) else e
                     for e in filters])

    @classmethod
    def _own(cls, filters):
        """A bank of these (new, unshared) estimators themselves (make_bank, from_state)."""
        bank = cls.__new__(cls)
        bank._setup(list(filters))
        return bank

    def _setup(self, filters):
        if not filters:
            raise ValueError("count must be an integer >= 1, got 0")
        f0 = filters[0]
        for i, e in enumerate(filters):
            if not isinstance(e, Estimator):
                raise ValueError(f"filters[{i}] is a {type(e).__name__}, not a fusion estimator")
            if (e.name, e.fs, e.frame, e.on_invalid) != (f0.name, f0.fs, f0.frame, f0.on_invalid):
                raise ValueError(f"filters[{i}] is ({e.name!r}, fs={e.fs}, frame={e.frame!r}, "
                                 f"on_invalid={e.on_invalid!r}); a bank's filters share those of "
                                 f"filters[0] ({f0.name!r}, fs={f0.fs}, frame={f0.frame!r}, "
                                 f"on_invalid={f0.on_invalid!r})")
        self._bind(filters, f0.on_invalid == "raise")
        self._count = len(filters)

    # --- stepping (update: BankCore.update, compiled) -------------------------------------
    def run(self, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike | None = None,
            dt: float | ArrayLike | None = None) -> np.ndarray:
        """T samples for every filter: gyr, acc, mag (T, count, 3) arrays (mag None: 6-axis);
        dt None (1/fs), a scalar, (T,) steps shared by the filters or (T, count). Returns
        (T, count, 4) quaternions, the same numbers as count separate est.run calls."""
        n = self._count
        g = np.asarray(gyr)
        T = g.shape[0] if g.ndim == 3 else -1
        what = f"(T, {n}, 3)"
        G = as_samples(gyr, "gyr", (T, n, 3), what, n)
        what = f"({T}, {n}, 3) as gyr"
        A = as_samples(acc, "acc", (T, n, 3), what, n)
        M = None if mag is None else as_samples(mag, "mag", (T, n, 3), what, n)
        D, h = None, self.dt_nominal
        if dt is not None:
            if np.ndim(dt) == 0:
                h = check_dt(dt)
            else:
                D = time_steps(dt, (T,))
                if D is not None:
                    D = np.ascontiguousarray(np.broadcast_to(D[:, None], (T, n)))
                else:
                    D = time_steps(dt, (T, n))
                    if D is None:
                        raise ValueError(f"dt must be None, a scalar or an array of shape ({T},) or "
                                         f"({T}, {n}), got dtype {np.asarray(dt).dtype} shape {np.shape(dt)}")
        self._enter(0)
        try:
            if self.on_invalid == "raise":
                check_samples(G, A, M, n, True)
            out = np.empty((T, n, 4))
            self._run(G, A, M, D, h, out)
        finally:
            self._exit()
        return out

    def reset(self, index: int | None = None, q0: ArrayLike | None = None) -> None:
        """Reset every filter (index None) or filter `index` only, as est.reset(q0): q0 None,
        one [w, x, y, z] for all, or with index None a (count, 4) array, one per filter."""
        n = self._count
        not_masked("q0", q0)        # np.asarray below would drop a (count, 4) array's mask
        if index is not None:
            integer("index", index, -n, n - 1)
            targets, q0s = [self._filters[index]], [q0]
        else:
            targets = self._filters
            if q0 is not None and np.ndim(q0) == 2:
                q = np.asarray(q0)
                if q.shape != (n, 4):
                    raise ValueError(f"q0 must be None, 4 numbers [w, x, y, z] or shape ({n}, 4), got shape {q.shape}")
                q0s = list(q)
            else:
                q0s = [q0] * n
        self._enter()
        try:
            # check every q0 before resetting any filter (est.reset's check): one bad row changes nothing
            for i, q in enumerate(q0s):
                if q is not None:
                    unit_q0(q, "q0" if len(q0s) == 1 or np.ndim(q0) == 1 else f"q0[{i}]")
            for e, q in zip(targets, q0s):
                e.reset(q)
        finally:
            self._exit()

    # --- reading --------------------------------------------------------------------------
    def __len__(self):
        return self._count

    def __getitem__(self, index):
        """A copy of filter `index` (a new estimator with its configuration and state);
        changing it does not change the bank (bank.load_state writes states back)."""
        n = self._count
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, numbers.Integral) or not -n <= index < n:
            raise IndexError(f"bank index must be an integer in [{-n}, {n - 1}], got {index!r}")
        return Estimator.from_state(self._read(lambda: self._filters[index].state()))

    def _read(self, f):
        self._enter(1)
        try:
            return f()
        finally:
            self._exit()

    def _stack(self, attr):
        vals = self._read(lambda: [getattr(e, attr) for e in self._filters])
        return None if vals[0] is None else np.array(vals)

    @property
    def quaternion(self):
        """(count, 4) attitudes [w, x, y, z] in the bank's frame."""
        return self._read(self._quaternions)

    euler = _stacked("euler", "(count, 3) ZYX Euler angles [yaw, pitch, roll], rad.")
    bias = _stacked("bias", "(count, 3) gyro biases (rad/s), or None for an estimator without one.")
    covariance = _stacked("covariance", "(count, k, k) state covariances, or None for an estimator without one.")
    initialised = _stacked("initialised", "(count,) bool: start attitude set.")

    @property
    def at_rest(self):
        """(count,) bool: the rest detector holds; None for an estimator without rest detection
        (one that does not declare the rest parameters)."""
        return self._stack("at_rest") if "rest_time" in self._filters[0].PARAMS else None

    @property
    def skipped(self):
        """Per sensor, (count,) counts of samples skipped as invalid since each filter's last reset."""
        s = self._read(lambda: [e.skipped for e in self._filters])
        return {k: np.array([d[k] for d in s], dtype=np.int64) for k in ("gyr", "acc", "mag")}

    name = _shared("name", "The estimator's name (fusion.available()).")
    fs = _shared("fs", "Sample rate (Hz).")
    frame = _shared("frame", '"ENU" or "NED", the frame of the quaternions in and out.')
    on_invalid = _shared("on_invalid", '"raise" or "skip", what a non-finite or all-zero sample does.')

    @property
    def params(self):
        """Each filter's parameters: a list of count dicts."""
        return [e.params for e in self._filters]

    # --- state, pickling, copies ----------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """The bank's state: a plain dict whose "filters" is the list of count est.state()
        dicts (each with its configuration). bank.load_state(s) / Bank.from_state(s) resume
        bit-identically; pickling and copy.deepcopy go through it."""
        return {"version": BANK_STATE_VERSION, "bank": True, "estimator": self.name,
                "count": self._count,
                "filters": self._read(lambda: [e.state() for e in self._filters])}

    @staticmethod
    def _check_header(state):
        state_header(state, BANK_STATE_KEYS, BANK_STATE_VERSION, "bank.state()")
        integer("state['count']", state["count"], 1, COUNT_MAX)
        fl = state["filters"]
        if not isinstance(fl, list) or len(fl) != state["count"]:
            raise ValueError(f"state['filters'] must be a list of {state['count']!r} filter states")

    def load_state(self, state: dict[str, Any]) -> None:
        """Restore every filter from bank.state() of a bank of the same estimator and count.
        Each filter keeps its configuration (est.load_state's rules); all filters' states are
        checked before any is written: a ValueError leaves the bank unchanged."""
        self._check_header(state)
        if state["estimator"] != self.name:
            raise ValueError(f"state is of a bank of {state['estimator']!r}, not {self.name!r}")
        if state["count"] != self._count:
            raise ValueError(f"state has count {state['count']!r} but this bank has count {self._count}")
        self._enter()
        try:
            for i, (e, s) in enumerate(zip(self._filters, state["filters"])):
                scratch = Estimator.from_state(e.state())
                try:
                    scratch.load_state(s)
                except ValueError as err:
                    raise ValueError(f"state['filters'][{i}]: {err}") from None
            for e, s in zip(self._filters, state["filters"]):
                e.load_state(s)
        finally:
            self._exit()

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> Bank:
        """A new bank with the configurations and states in `state` (from bank.state())."""
        cls._check_header(state)
        filters = []
        for i, s in enumerate(state["filters"]):
            try:
                filters.append(Estimator.from_state(s))
            except ValueError as err:
                raise ValueError(f"state['filters'][{i}]: {err}") from None
            if filters[i].name != state["estimator"]:
                raise ValueError(f"state['filters'][{i}] is of estimator {filters[i].name!r} but "
                                 f"state['estimator'] is {state['estimator']!r}; they must agree")
        return cls._own(filters)

    def __reduce__(self):
        return (Bank.from_state, (self.state(),))

    def __repr__(self):
        return f"<fusion bank of {self._count} {self.name!r}, fs={self.fs!r}, frame={self.frame!r}>"
