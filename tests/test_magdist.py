"""Magnetic disturbance detection and rejection (fusion/_magdist.pxd, docs/estimators.md,
"Magnetic disturbances"): the kernels against their numpy references while the detector is
busy, what it does with a passing and with an attached magnet, and its parameters."""
import numpy as np
import pytest

import fusion
from fusion import quat
import reference as ref
import reference_aekf as ra
import reference_madgwick_ukf_cfekf as rm
from _helpers import FS, errors_deg, qdiff, rms, scenario

MAGNETIC = ("ekf", "iir-ekf", "aekf", "ukf", "mahony", "madgwick", "cf-ekf")
REFS = {"ekf": ref.RefEKF, "mahony": ref.RefMahony, "aekf": ra.RefAEKF, "ukf": rm.RefUKF,
        "cf-ekf": rm.RefCFEKF, "madgwick": rm.RefMadgwick}
# madgwick with its low-pass amplifies round-off over long runs (tests/test_madgwick_ukf_cfekf.py,
# CASES): its kernel-against-reference runs here go without it
REF_EXTRA = {"madgwick": {"acc_lowpass": 0.0}}
TOL = 1e-9


def attached(n=6000, t_on=20.0, offset=(0.8, -0.5, 0.6)):
    """The test_aekf scenario without a passing disturbance, and from t_on s a constant
    body-frame offset (a magnet fixed to the sensor: a new hard-iron offset) of `offset`
    times the field's norm."""
    q, gyr, acc, mag, _, _ = scenario(n=n, seed=3, burst_amp=0.0, disturb=None)
    on = np.arange(n) / FS >= t_on
    mag = mag.copy()
    mag[on] += np.asarray(offset) * np.median(np.linalg.norm(mag, axis=1))
    return q, gyr, acc, mag, on


def new_field(n=6000, t_on=20.0, offset=(0.3, -0.4, 0.3)):
    """As attached, but the offset is fixed in the earth frame (a new homogeneous field: the
    sensor carried to another room): a field that keeps its direction while the sensor turns."""
    q, gyr, acc, mag, _, _ = scenario(n=n, seed=3, burst_amp=0.0, disturb=None)
    on = np.arange(n) / FS >= t_on
    mag = mag.copy()
    d = np.asarray(offset) * np.median(np.linalg.norm(mag, axis=1))
    mag[on] += quat.rotate_inverse(q[on], np.broadcast_to(d, (int(on.sum()), 3)))
    return q, gyr, acc, mag, on


@pytest.mark.parametrize("name", sorted(REFS))
@pytest.mark.parametrize("case", ["passing", "attached", "new field", "start in motion"])
def test_kernel_equals_reference_while_disturbed(name, case):
    """Each kernel against its reference (1e-9) over a passing disturbance (15 s), an
    attached magnet (from 20 s, rejected while it turns with the sensor) and a new field (from
    20 s, magdist_time 10 s so that the reference is re-learned), with the detector rejecting
    samples in each, and over a start in linear acceleration (the settling before the dip is
    judged, with the tilt several degrees off)."""
    if case == "passing":
        q_true, gyr, acc, mag, _, _ = scenario(n=6000, seed=9, burst_amp=0.0, disturb=(20.0, 35.0))
        params = {}
    elif case == "start in motion":
        q_true, gyr, acc, mag = start_in_motion(0)
        params = {"magdist_new_time": 2.0}
    else:
        q_true, gyr, acc, mag, _ = attached() if case == "attached" else new_field()
        params = {"magdist_time": 10.0}
    params.update(REF_EXTRA.get(name, {}))
    est = fusion.make(name, FS, **params)
    r = REFS[name](FS, **params)
    q = est.run(gyr, acc, mag)
    qr = r.run(gyr, acc, mag)
    assert qdiff(q, qr) < TOL
    assert est.mag_rejected == r.mag_rejected if name != "cf-ekf" else est.mag_rejected == r.cf.mag_rejected
    assert est.mag_rejected > 100 or case == "start in motion"


@pytest.mark.parametrize("name", MAGNETIC)
def test_passing_magnet_leaves_the_heading_on_the_gyro(name):
    """A 15 s disturbance (norm +17 %, field heading 37 deg off): with detection (default)
    the heading error over the episode and the 15 s after it stays below 5 deg, and below a
    third of the error without it (magdist_time=0; not for the aekf, whose document's own
    gate rejects the disturbance as well). mahony learns the vertical gyro bias only through
    its integral, so its heading drifts with the scenario's bias (0.3-0.5 deg/s) while the field
    is rejected: 5.01 deg max at the 5 deg dip tolerance, 2.49 at 10 deg, where the drift began
    from an offset of the other sign (19.9 rms without detection): held to the third only.
    madgwick, with its bias gain zeta on since issue 19's sixth pass, is held to both (2.94)."""
    q_true, gyr, acc, mag, _, dist = scenario(n=9000, seed=9, burst_amp=0.0, disturb=(40.0, 55.0))
    after = slice(4000, 7000)
    on = errors_deg(fusion.make(name, FS).run(gyr, acc, mag), q_true)[1][after]
    off = errors_deg(fusion.make(name, FS, magdist_time=0).run(gyr, acc, mag), q_true)[1][after]
    print(name, round(on.max(), 2), round(off.max(), 2))
    assert name == "mahony" or on.max() < 5.0
    assert name == "aekf" or rms(on) < rms(off) / 3


@pytest.mark.parametrize("name", MAGNETIC)
def test_attached_magnet_is_rejected_for_as_long_as_it_turns_with_the_sensor(name):
    """A magnet fixed to the sensor from 20 s (40 s of it): its field turns with the sensor,
    so it is no earth field however long it stays, and it is not re-learned after
    magdist_time (10 s here; before the field-direction test every filter re-learned it there
    and turned its heading by it): all but a few of its samples are rejected, and while the
    heading runs on the gyro (20-30 s) its error stays below 10 deg (the scenario's gyro bias,
    0.027 rad/s, turns an unlearned heading by 15 deg in 10 s)."""
    q_true, gyr, acc, mag, on = attached()
    est = fusion.make(name, FS, magdist_time=10.0)
    e = errors_deg(est.run(gyr, acc, mag), q_true)[1]
    rejected = est.mag_rejected
    print(name, rejected, int(on.sum()), round(e[2000:3000].max(), 2))
    assert rejected > 0.99 * on.sum()
    assert e[2000:3000].max() < 10.0


@pytest.mark.parametrize("name", MAGNETIC)
def test_a_new_field_is_relearned(name):
    """A new homogeneous field from 20 s (an earth-frame offset): rejected for at most
    magdist_time (10 s here) at a stretch, then it is the reference, though the sensor turns
    all the while (its direction holds in the navigation frame)."""
    q_true, gyr, acc, mag, on = new_field()
    est = fusion.make(name, FS, magdist_time=10.0)
    est.run(gyr, acc, mag)
    print(name, est.mag_rejected)
    assert 0.5 * 10.0 * FS < est.mag_rejected < 15.0 * FS


def start_in_motion(seed, duration=120.0):
    """fusion.scenarios' "shaking" (linear-acceleration bursts of 8 m/s², 30 a minute) with a
    1 deg/s gyro bias: the first accelerometer samples carry linear acceleration, and the
    filters start with a tilt up to 16 deg off (seed 0 at 120 s: off by 16 deg at most in the
    first 2 s)."""
    from fusion.scenarios import make_scenario
    b = np.random.default_rng(seed).normal(size=3)
    sc = make_scenario("shaking", fs=FS, duration=duration, seed=seed,
                       gyro_bias=np.radians(1.0) * b / np.linalg.norm(b))
    return sc.q_true, sc.gyr, sc.acc, sc.mag


@pytest.mark.parametrize("name", MAGNETIC)
def test_a_start_in_motion_does_not_hold_the_true_field_out(name):
    """The dip is judged with the filter's attitude, so a reference dip taken at the first
    sample, with the tilt still off, held the undisturbed field out as disturbed for
    magdist_time (60 s): before the settling, on this recording every filter but madgwick
    rejected 6,000-6,030 samples and its heading error was 19.5-22.3 deg rms against
    1.2-3.0 with detection off. The dip is judged after the first second (MAGD_FIRST_TIME):
    nothing is rejected here, and the heading is that of the detection off."""
    q_true, gyr, acc, mag = start_in_motion(0)
    est = fusion.make(name, FS)
    on = errors_deg(est.run(gyr, acc, mag), q_true)[1]
    off = errors_deg(fusion.make(name, FS, magdist_time=0).run(gyr, acc, mag), q_true)[1]
    print(name, est.mag_rejected, round(rms(on), 2), round(rms(off), 2))
    assert est.mag_rejected < 0.01 * len(gyr)
    assert rms(on) < 1.1 * rms(off) + 0.1


def test_detection_off_rejects_nothing_and_6_axis_is_unchanged():
    q_true, gyr, acc, mag, _, _ = scenario(n=3000, seed=9, burst_amp=0.0, disturb=(10.0, 20.0))
    for name in MAGNETIC:
        est = fusion.make(name, FS, magdist_time=0)
        est.run(gyr, acc, mag)
        assert est.mag_rejected == 0
        a = fusion.make(name, FS).run(gyr, acc)
        b = fusion.make(name, FS, magdist_time=0).run(gyr, acc)
        assert np.array_equal(a, b)


@pytest.mark.parametrize("name", MAGNETIC)
def test_state_carries_the_detector(name):
    """state() / load_state() mid-disturbance continues bit for bit."""
    q_true, gyr, acc, mag, _, _ = scenario(n=3000, seed=9, burst_amp=0.0, disturb=(10.0, 25.0))
    a = fusion.make(name, FS)
    qa = a.run(gyr, acc, mag)
    b = fusion.make(name, FS)
    b.run(gyr[:1500], acc[:1500], mag[:1500])
    c = fusion.make(name, FS)
    c.load_state(b.state())
    assert np.array_equal(c.run(gyr[1500:], acc[1500:], mag[1500:]), qa[1500:])
    assert c.mag_rejected == a.mag_rejected


@pytest.mark.parametrize("name", MAGNETIC)
@pytest.mark.parametrize("param, bad", [("magdist_time", -1.0), ("magdist_time", float("nan")),
                                        ("magdist_norm_tol", 0.0), ("magdist_dip_tol", 91.0),
                                        ("magdist_new_time", 0.0), ("mag_update", "full"),
                                        ("magdist_time", "60")])
def test_bad_parameters_are_named(name, param, bad):
    with pytest.raises(ValueError, match=param):
        fusion.make(name, FS, **{param: bad})


@pytest.mark.parametrize("name", MAGNETIC)
def test_defaults(name):
    est = fusion.make(name, FS)
    assert est.mag_update == "heading"
    got = (est.magdist_time, est.magdist_norm_tol, est.magdist_dip_tol, est.magdist_new_time)
    assert got == tuple(ref.MAGDIST_PARAMS[k] for k in ("magdist_time", "magdist_norm_tol", "magdist_dip_tol",
                                                       "magdist_new_time"))


@pytest.mark.parametrize("name", ["ekf", "mahony", "ukf"])
@pytest.mark.parametrize("tau", [0.3, 3.0])
def test_acc_lowpass_kernel_equals_reference(name, tau):
    """acc_lowpass (fusion/_acclp.pxd, shared by the ekf family, mahony and the ukf): the
    kernel against its reference (1e-9) with linear-acceleration bursts (6 m/s^2), 9-axis
    and 6-axis, in the batch loop and sample by sample."""
    q_true, gyr, acc, mag, _, _ = scenario(n=3000, seed=5, burst_amp=6.0, disturb=None)
    for m in (mag, None):
        est = fusion.make(name, FS, acc_lowpass=tau)
        q = est.run(gyr, acc, m)
        assert qdiff(q, REFS[name](FS, acc_lowpass=tau).run(gyr, acc, m)) < TOL
        one = fusion.make(name, FS, acc_lowpass=tau)
        q1 = np.array([one.update(g, a, None if m is None else mm) for g, a, mm in
                       zip(gyr[:500], acc[:500], (m if m is not None else gyr)[:500])])
        assert qdiff(q1, q[:500]) < 1e-12
