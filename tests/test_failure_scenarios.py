"""The failure scenarios of issue 19 (fusion.scenarios.FAILURE_SCENARIOS: fast rotation at
286 Hz, a magnet attached to the sensor, a magnet passed nearby, phone-like vibration,
tapping): every estimator that issue names stays bounded in each, with one bound for all.

Bounds (deg, RMSE over the 60 s, default parameters, scenario seed 0): 9-axis total below 4
and inclination below 2.5; 6-axis inclination below 2.5 (the 6-axis heading drifts with the
scenario's unlearned gyro bias, 0.014 rad/s, and is not scored). 4 deg is below the 4.89 deg
the held-out set asks of every seed estimator. `madgwick` is held to them since it has the
shared disturbance rejection and low-pass (before: 6.7 / 8.0 deg total with the magnets; now
3.4 attached, 1.8 passing). With issue 19's fourth-pass defaults (the weaker magnetometer) the
largest 9-axis totals were madgwick 3.44 (attached) and cf-ekf 3.40 (fast rotation; 0.63 since
its sliding mean is off by default, issue 19's eleventh pass); the ekf's 2.49 (attached). The
3-seed means bounded the magnetometer's weight (docs/accuracy.md).
In "magnet-stays" (a strong magnet fixed to the sensor for the last 40 s) every filter rejects
the field for good and the heading runs on the gyro: there the total's bound is the 4.89 deg
itself (seed 0: mahony 4.20, ekf 3.24, aekf 0.69; VQF, which re-learns the magnet's field
as a new one, 13.2 as a 4-seed mean against the ekf's 3.9)."""
import pytest

import fusion
from fusion import scenarios
from benchmarks import compare

NAMES = ("ekf", "ekf-lp", "iir-ekf", "aekf", "ukf", "mahony", "madgwick", "cf-ekf")
TOTAL_9, INCL = 4.0, 2.5
TOTAL_9_GYRO_HEADING = 4.89


@pytest.fixture(scope="module", params=sorted(scenarios.FAILURE_SCENARIOS))
def scenario(request):
    return scenarios.failure_scenario(request.param)


@pytest.mark.parametrize("name", NAMES)
def test_error_stays_bounded(scenario, name):
    sc = scenario
    q9 = fusion.make(name, sc.fs).run(sc.gyr, sc.acc, sc.mag, dt=sc.dt)
    q6 = fusion.make(name, sc.fs).run(sc.gyr, sc.acc, dt=sc.dt)
    s9, _, _, _ = compare.score_mode(q9, sc.q_true, "9-axis")
    s6, _, _, _ = compare.score_mode(q6, sc.q_true, "6-axis")
    print(sc.name, name, round(s9["total"], 2), round(s9["inclination"], 2), round(s6["inclination"], 2))
    bound = TOTAL_9_GYRO_HEADING if sc.name == "magnet-stays" else TOTAL_9
    assert s9["total"] < bound and s9["inclination"] < INCL and s6["inclination"] < INCL


def test_scenarios_are_what_they_say():
    fast = scenarios.failure_scenario("fast-rotation")
    assert fast.fs == 286.0 and abs(fast.omega).max() > 5.0
    for name in ("magnet-attached", "magnet-stays"):
        att = scenarios.failure_scenario(name)
        assert att.mag_disturbed[int(25 * att.fs)] and not att.mag_disturbed[int(10 * att.fs)]
    assert scenarios.failure_scenario("magnet-stays").mag_disturbed[-1]
    for name in ("vibration", "tapping"):
        sc = scenarios.failure_scenario(name)
        assert 0.01 < sc.acc_disturbed.mean() < 0.5
    with pytest.raises(ValueError, match="unknown failure scenario"):
        scenarios.failure_scenario("earthquake")
