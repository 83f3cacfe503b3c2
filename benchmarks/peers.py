"""Our estimators and the peer libraries behind one calling shape, each peer fed in its own
units and frame: the one copy of that feeding logic, shared by throughput.py and accuracy.py.

Peers (``pip install '.[bench]'``) and how they are fed:

- ``vqf.VQF`` / ``vqf.BasicVQF``: rad/s, m/s^2 (specific force), magnetometer in uT; output
  body -> ENU. One constant sample time, set at construction (no per-sample dt): ``Data.ts``,
  the mean step of the time stamps (``1/fs`` when they are even). ``vqf_method(...,
  nominal=True)`` takes ``1/fs`` instead, as the reference figures of the data folder's README
  ("Recorded IMU data with a reference orientation") do
  (on ese650 the nominal fs, ~104.4 Hz, is 4 % off the stamps' mean rate of 100 Hz).
- ``imufusion.Ahrs`` (1.3): deg/s, g, uT, ``CONVENTION_ENU``; output body -> ENU. Sample
  period set with ``set_sample_period``: ``1/fs``, or before every sample from the time
  stamps when they are uneven. No batch API: "run" is its Python loop.
- ``ahrs.filters.Madgwick`` / ``Mahony`` (0.4): rad/s, m/s^2 (specific force), nT. Output
  body -> NWU for Madgwick (its magnetic reference is north on x: ``[|h_xy|, 0, h_z]``) and
  body -> ENU for Mahony (north on y: ``[0, |h_xy|, h_z]``); z up for both. Per-sample ``dt``
  argument.
- ``ahrs.filters.EKF``: rad/s, gravity instead of specific force (see ``ahrs_method``), nT,
  default frame NED with the field's dip angle as ``magnetic_ref``; output body -> NED.
  Per-sample ``dt`` argument.

``Method.to_enu`` turns any output into body -> ENU quaternions (our convention, the one the
scoring uses).
"""
import numpy as np

import fusion
from fusion import quat
from fusion.constants import GRAVITY
from fusion.scenarios import make_scenario

UT = 50.0                    # |B| in uT the peers get when the data's unit is arbitrary

# body -> NWU / NED quaternions are turned into body -> ENU by a fixed rotation on the left
_TO_ENU = {"ENU": np.array([1.0, 0.0, 0.0, 0.0]),
           "NWU": np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]),      # +90 deg about z
           "NED": np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])}      # 180 deg about (1,1,0)


# ---------------------------------------------------------------------------------------------
# data

def dip_from_samples(acc, mag, n=100):
    """Magnetic dip angle (deg, positive down) from the mean of the first ``n`` samples:
    the angle between specific force (up) and field, minus 90 deg. For peers that need the
    dip as a parameter (ahrs.EKF) on recordings where it is not given; no reference used."""
    a, m = np.mean(acc[:n], axis=0), np.mean(mag[:n], axis=0)
    c = np.dot(a, m) / (np.linalg.norm(a) * np.linalg.norm(m))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))) - 90.0)


class Data:
    """One recording in every library's units. All arrays C-contiguous float64, (N, 3).

    ``dt`` is None when the time stamps are even at ``1/fs`` (every library then runs at its
    nominal rate), else the (N,) step into each sample, for the peers that take it; ``ts``
    is the one constant sample time for the peers that take no per-sample dt (the mean step
    of the stamps, ``1/fs`` when even). ``mag_ut_per_unit`` scales our magnetometer unit to uT;
    ``dip_deg`` is the field's dip."""

    def __init__(self, gyr, acc, mag=None, *, fs, dt=None, q_true=None, mag_ut_per_unit=None,
                 dip_deg=None):
        c = np.ascontiguousarray
        self.fs = float(fs)
        self.n = len(gyr)
        if dt is not None and np.allclose(dt, 1.0 / self.fs, rtol=1e-9, atol=0.0):
            dt = None
        self.dt = None if dt is None else c(dt, dtype=np.float64)
        self.ts = 1.0 / self.fs if self.dt is None or self.n < 2 else float(np.mean(self.dt[1:]))
        self.q_true = q_true
        self.gyr = c(gyr, dtype=np.float64)                   # rad/s
        self.acc = c(acc, dtype=np.float64)                   # m/s^2
        self.gyr_dps = c(np.degrees(self.gyr))                # deg/s
        self.acc_g = c(self.acc / GRAVITY)                          # g
        self.acc_down = c(-self.acc)                          # m/s^2, gravity (ahrs.EKF, see there)
        self.mag = self.mag_ut = self.mag_nt = None
        self.dip_deg = dip_deg
        if mag is not None:
            self.mag = c(mag, dtype=np.float64)               # the recording's unit
            if mag_ut_per_unit is None:                       # arbitrary unit: scale to |B| = 50 uT
                mag_ut_per_unit = UT / float(np.median(np.linalg.norm(self.mag, axis=1)))
            self.mag_ut = c(self.mag * mag_ut_per_unit)       # uT
            self.mag_nt = c(self.mag_ut * 1e3)                # nT
            if dip_deg is None:
                self.dip_deg = dip_from_samples(self.acc, self.mag)

    @classmethod
    def from_scenario(cls, sc, n=None):
        """A ``fusion.scenarios.Scenario`` (its first ``n`` samples if given)."""
        f = np.asarray(sc.field, dtype=float)
        # dip angle of the scenario field (ENU [east, north, up]); ahrs.EKF takes it as magnetic_ref
        dip = float(np.degrees(np.arctan2(-f[2], np.hypot(f[0], f[1]))))
        k = slice(n)
        # the field's unit varies (make_scenario: |B| = 0.5; seed scenarios: uT): |B| -> 50 uT
        return cls(sc.gyr[k], sc.acc[k], None if sc.mag is None else sc.mag[k], fs=sc.fs,
                   dt=sc.dt[k], q_true=sc.q_true[k], mag_ut_per_unit=UT / float(np.linalg.norm(f)),
                   dip_deg=dip)

    @classmethod
    def mixed(cls, n, fs=100.0, seed=1):
        """The ``mixed`` synthetic scenario, ``n`` samples (throughput.py's data)."""
        return cls.from_scenario(make_scenario("mixed", fs=fs, duration=n / fs, seed=seed))

    @classmethod
    def from_trial(cls, tr, n=None):
        """A ``fusion.datasets.Trial`` (its first ``n`` samples if given): magnetometer unit
        arbitrary (scaled to 50 uT), dip from the first second of samples, the trial's time
        stamps."""
        k = slice(n)
        mag = None if tr.mag is None else tr.mag[k]
        return cls(tr.gyr[k], tr.acc[k], mag, fs=tr.fs, dt=tr.dt[k], q_true=tr.quat[k],
                   dip_deg=None if mag is None else dip_from_samples(tr.acc[k], mag, int(tr.fs)))


# ---------------------------------------------------------------------------------------------
# methods: each builds, for (data, n, nine), a fresh zero-argument callable that processes the
# first n samples and returns the last quaternion ("update") or the (n, 4) quaternions ("run").

class Method:
    """``nav``: the frame the output quaternions rotate body vectors into ("ENU", "NWU",
    "NED"); ``per_sample_dt``: whether "run" follows uneven time stamps (``Data.dt``);
    ``feeding``: one line on units / frame / timing for reports."""

    def __init__(self, name, group, update=None, run=None, run_note="", drifts=False, nav="ENU",
                 per_sample_dt=True, feeding=""):
        self.name, self.group, self.drifts = name, group, drifts
        self.nav = nav
        self.up = -1.0 if nav == "NED" else 1.0    # +1: output is body -> z-up frame; -1: z-down
        self.builders = {"update": update, "run": run}
        self.run_note = run_note
        self.per_sample_dt = per_sample_dt
        self.feeding = feeding

    def to_enu(self, q):
        """Output quaternions (N, 4) as body -> ENU."""
        return quat.mul(_TO_ENU[self.nav], np.asarray(q, dtype=float))

    def run_enu(self, d, nine):
        """The whole recording ``d`` in one "run" call: (N, 4) body -> ENU quaternions."""
        return self.to_enu(np.array(self.builders["run"](d, d.n, nine)(), dtype=float))


def ours(name):
    def update(d, n, nine):
        est = fusion.make(name, d.fs)
        upd = est.update
        g, a = d.gyr[:n], d.acc[:n]
        if nine:
            m = d.mag[:n]

            def go():
                q = None
                for gi, ai, mi in zip(g, a, m):
                    q = upd(gi, ai, mi)
                return q
        else:
            def go():
                q = None
                for gi, ai in zip(g, a):
                    q = upd(gi, ai)
                return q
        return go

    def run(d, n, nine):
        est = fusion.make(name, d.fs)
        g, a, m = d.gyr[:n], d.acc[:n], (d.mag[:n] if nine else None)
        dt = None if d.dt is None else d.dt[:n]
        return lambda: est.run(g, a, m, dt=dt)

    return Method(f"fusion.{name}", "ours", update, run, drifts=(name == "gyro"),
                  feeding="rad/s, m/s^2, magnetometer in the data's unit; per-sample dt")


def vqf_method(cls_name, nominal=False):
    """``nominal``: sample time ``1/fs`` rather than ``Data.ts`` (the README's feeding)."""
    import vqf
    cls = getattr(vqf, cls_name)

    def ts(d):
        return 1.0 / d.fs if nominal else d.ts

    def update(d, n, nine):
        v = cls(ts(d))
        return _last_loop(v.update, v.getQuat9D if nine else v.getQuat6D, d.gyr[:n], d.acc[:n],
                          d.mag_ut[:n] if nine else None)

    def run(d, n, nine):
        v = cls(ts(d))                  # sample time fixed at construction: no per-sample dt
        g, a = d.gyr[:n], d.acc[:n]
        if nine:
            m = d.mag_ut[:n]
            return lambda: v.updateBatch(g, a, m)["quat9D"]
        return lambda: v.updateBatch(g, a)["quat6D"]

    return Method(f"vqf.{cls_name}" + (" (Ts=1/fs)" if nominal else ""), "peer", update, run,
                  per_sample_dt=False,
                  feeding="rad/s, m/s^2, uT; ENU; constant Ts = "
                          + ("1/fs (nominal)" if nominal else "mean step of t") + " (no per-sample dt API)")


def _last_loop(upd, get, g, a, m=None):
    """The timed per-sample loop of a peer: ``upd`` then ``get`` on every sample, keeping the
    last output; one closure per case (with or without ``m``), so that the loop holds no branch."""
    if m is not None:
        def go():
            q = None
            for gi, ai, mi in zip(g, a, m):
                upd(gi, ai, mi)
                q = get()
            return q
    else:
        def go():
            q = None
            for gi, ai in zip(g, a):
                upd(gi, ai)
                q = get()
            return q
    return go


def _imufusion_ahrs(d):
    import imufusion
    ahrs = imufusion.Ahrs()
    s = imufusion.AhrsSettings()          # defaults, but ENU like our data and our fs
    s.convention = imufusion.CONVENTION_ENU
    s.sample_rate = d.fs
    ahrs.set_settings(s)
    ahrs.set_sample_period(1.0 / d.fs)    # this version takes no dt argument in update()
    return ahrs


def _imufusion_uneven_loop(ahrs, g, a, m, dts, out):
    """The sample period set before every sample (accuracy runs only; throughput's data is
    even, so its timed loops are unchanged)."""
    per, get = ahrs.set_sample_period, ahrs.get_quaternion
    if m is not None:
        upd = ahrs.update

        def go():
            for i, (gi, ai, mi, ti) in enumerate(zip(g, a, m, dts)):
                per(ti)
                upd(gi, ai, mi)
                out[i] = get()
            return out
    else:
        upd = ahrs.update_no_magnetometer

        def go():
            for i, (gi, ai, ti) in enumerate(zip(g, a, dts)):
                per(ti)
                upd(gi, ai)
                out[i] = get()
            return out
    return go


def _imufusion_even_loop(ahrs, g, a, m, out):
    """One closure per case, so that the timed loop holds no branch; out=None keeps only the last."""
    get = ahrs.get_quaternion
    upd = ahrs.update if m is not None else ahrs.update_no_magnetometer
    if out is None:
        return _last_loop(upd, get, g, a, m)
    if m is not None:
        def go():
            for i, (gi, ai, mi) in enumerate(zip(g, a, m)):
                upd(gi, ai, mi)
                out[i] = get()
            return out
    else:
        def go():
            for i, (gi, ai) in enumerate(zip(g, a)):
                upd(gi, ai)
                out[i] = get()
            return out
    return go


def _imufusion_loops(d, n, nine, store):
    ahrs = _imufusion_ahrs(d)
    g, a = d.gyr_dps[:n], d.acc_g[:n]
    out = np.empty((n, 4)) if store else None
    m = d.mag_ut[:n] if nine else None
    if store and d.dt is not None:
        return _imufusion_uneven_loop(ahrs, g, a, m, d.dt[:n], out)
    return _imufusion_even_loop(ahrs, g, a, m, out)


def imufusion_method():
    return Method("imufusion.Ahrs", "peer",
                  lambda d, n, nine: _imufusion_loops(d, n, nine, False),
                  lambda d, n, nine: _imufusion_loops(d, n, nine, True),
                  run_note="Python loop, no batch API",
                  feeding="deg/s, g, uT; CONVENTION_ENU; set_sample_period(dt) before each sample")


def _ahrs_update_loop(q0, upd, g, a, m):
    """The per-sample loop of an ahrs filter's update; m=None for 6 axes."""
    if m is not None:
        def go():
            q = q0
            for gi, ai, mi in zip(g, a, m):
                q = upd(q, gi, ai, mi)
            return q
    else:
        def go():
            q = q0
            for gi, ai in zip(g, a):
                q = upd(q, gi, ai)
            return q
    return go


def _ahrs_uneven_run(stepper, d, nine, g, a, m, n):
    """The batch constructor's own loop (start from the first sample, then update from the
    second on), with each sample's dt."""
    dts = d.dt[:n]

    def go():
        q0, upd = stepper(d, nine, m)
        out = np.empty((n, 4))
        out[0] = q0
        if nine:
            for i in range(1, n):
                out[i] = upd(out[i - 1], g[i], a[i], m[i], dt=dts[i])
        else:
            for i in range(1, n):
                out[i] = upd(out[i - 1], g[i], a[i], dt=dts[i])
        return out
    return go


def ahrs_method(cls_name):
    from ahrs import filters
    cls = getattr(filters, cls_name)
    # ahrs.EKF runs in its default NED frame and models the accelerometer as reading gravity
    # (its a_ref is [0, 0, 1] in NED), the opposite sign of the specific force the others
    # take: fed the specific force it settles upside down. (Its frame="ENU" option gave a
    # worse 9-axis tilt on this data, so the default is used.) Madgwick and Mahony take the
    # specific force and return body -> z-up quaternions, but with magnetic north on x (NWU)
    # for Madgwick and on y (ENU) for Mahony: their field references differ.
    ekf = cls_name == "EKF"
    acc_of = (lambda d: d.acc_down) if ekf else (lambda d: d.acc)

    def kwargs(d):
        kw = dict(frequency=d.fs)
        if ekf:
            kw.update(frame="NED", magnetic_ref=d.dip_deg)
        return kw

    def stepper(d, nine, m):
        """(q0 from the library's own start on the first sample, per-sample update)."""
        g, a = d.gyr, acc_of(d)
        q0 = cls(gyr=g[:1], acc=a[:1], mag=None if m is None else m[:1], **kwargs(d)).Q[0].copy()
        f = cls(**kwargs(d))
        if cls_name == "Madgwick" and nine:
            f.gain = f.gain_marg         # the gain its batch constructor picks when given mag
        if ekf:
            if nine:
                # ahrs 0.4.0: EKF.h()/dhdq() pick 6- or 9-axis from self.mag (set only by the
                # batch constructor), so a per-sample 9-axis update needs it set by hand
                f.mag = m
            return q0, f.update
        return q0, (f.updateMARG if nine else f.updateIMU)

    def update(d, n, nine):
        g, a = d.gyr[:n], acc_of(d)[:n]
        m = d.mag_nt[:n] if nine else None
        q0, upd = stepper(d, nine, m)
        return _ahrs_update_loop(q0, upd, g, a, m)

    def run(d, n, nine):
        g, a = d.gyr[:n], acc_of(d)[:n]
        m = d.mag_nt[:n] if nine else None
        if d.dt is None:                 # even stamps: the library's batch constructor
            kw = kwargs(d)
            return lambda: cls(gyr=g, acc=a, mag=m, **kw).Q
        return _ahrs_uneven_run(stepper, d, nine, g, a, m, n)      # uneven stamps

    nav = {"EKF": "NED", "Madgwick": "NWU"}.get(cls_name, "ENU")
    units = ("rad/s, gravity (-specific force) m/s^2, nT; NED, magnetic_ref = dip" if ekf
             else f"rad/s, m/s^2, nT; output {nav}")
    return Method(f"ahrs.{cls_name}", "peer", update, run, nav=nav,
                  feeding=units + "; per-sample dt argument")


def all_methods(log, names=None):
    """Ours (``names``, default ``fusion.available()``) then every importable peer."""
    methods = [ours(name) for name in (names or fusion.available())]
    peers = []
    try:
        import vqf
        peers.append(vqf_method("VQF"))
        if hasattr(vqf, "BasicVQF"):
            peers.append(vqf_method("BasicVQF"))
    except ImportError as e:
        log(f"skipping vqf: {e}")
    try:
        peers.append(imufusion_method())
    except ImportError as e:
        log(f"skipping imufusion: {e}")
    try:
        for c in ("Madgwick", "Mahony", "EKF"):
            peers.append(ahrs_method(c))
    except ImportError as e:
        log(f"skipping ahrs: {e}")
    return methods + peers


# ---------------------------------------------------------------------------------------------
# sanity: finite, unit-norm, moving output that tracks the true tilt

def tilt_error_deg(q_est, q_true, up=1.0):
    """Angle between the estimated and the true "up" in the body frame, in deg.

    q_est rotates body vectors into a navigation frame whose z axis points up (up=+1: ENU,
    NWU) or down (up=-1: NED). Sign-aware: an estimate that settles upside down scores ~180."""
    ez = np.array([0.0, 0.0, 1.0])
    u = quat.rotate_inverse(np.atleast_2d(q_true), ez)
    v = up * quat.rotate_inverse(quat.normalise(np.atleast_2d(q_est)), ez)
    return np.degrees(np.arccos(np.clip(np.sum(u * v, axis=-1), -1.0, 1.0)))


def sanity(method, kind, nine, d, n):
    out = np.asarray(method.builders[kind](d, n, nine)(), dtype=float)
    if kind == "update":
        q, ref = out.reshape(1, 4), d.q_true[n - 1:n]
    else:
        q, ref = out.reshape(-1, 4)[n // 2:], d.q_true[n // 2:n]
    finite = bool(np.isfinite(q).all())
    unit = finite and bool(np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6))
    moved = finite and bool(np.ptp(q, axis=0).max() > 1e-3) if len(q) > 1 else True
    err = float(np.median(tilt_error_deg(q, ref, method.up))) if finite else float("nan")
    ok = finite and unit and moved and (err < 10.0 or method.drifts)
    return ok, err


def main(argv=None):
    """``python benchmarks/peers.py``: which methods the benchmarks would compare here."""
    import argparse
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Without options: list our estimators and the peers importable here.")
    ap.parse_args(argv)
    for m in all_methods(print):
        print(f"{m.name:18s} {m.feeding}")
    return 0


if __name__ == "__main__":
    import sys
    sys.exit(main())
