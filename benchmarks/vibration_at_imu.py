"""How strong is the drive vibration the estimators see, and where is it in frequency?

    .venv/bin/python benchmarks/vibration_at_imu.py [--seconds 12] [--drives 0.3,0.6,1.0] [--loop 10]

Drives the environment's robot straight at a constant voltage (action (drive, 0)) for
``--seconds``, discards the first 5 s (the start), and prints, for the realistic (v1) and the
ideal (v0) robot, from the IMU samples that go to the estimator (the default MPU-9250,
calibrated, 200 Hz, its DLPF): the speed reached, the std of |acc| and of each axis, and the
share of the accelerometer's fluctuation power (mean removed) below the iir-ekf's
Butterworth cut-off (``cutoff_hz``, 40 Hz) against 40 Hz to Nyquist, with the strongest
spectral lines. Then, in the same straight run at ``--drive-est`` (default 0.6), the rms
inclination (tilt) and heading error of ``ekf``, ``iir-ekf`` (its default 40 Hz and a 10 Hz
cut-off, below the motor's tone: a diagnosis, not a proposed default) and ``ukf`` in the
loop (``info`` q_est against q_true at every control step, ``fusion.metrics.attitude_errors``),
on the realistic robot, on it without the drive vibration (its ``vib_*`` fields 0: every other
realism kept) and on the ideal robot, mean over ``--seeds`` seeds. With ``--loop N``: the
same estimators under the PID in both tasks (flat floor, seeds 0..N-1), the mean
``tilt_error`` and its paired difference against ``ekf``, with and without the vibration.
With ``--bumps``: only each bump's peak |acc| - g at the IMU, 400 against 1600 Hz physics, for
the ideal IMU and the MPU-9250 at each range setting (+-2, 4, 8, 16 g), straight at full and
0.6 drive over bumps 1 m apart (``envs.convergence.bump_peaks``; docs/envs/robot.md).
"""
import argparse

import numpy as np


def measure(drive, seconds, realism, seed=0):
    from envs.sphere import SphereRobotEnv
    env = SphereRobotEnv(task="track", estimator="truth", realism=realism, episode_s=seconds + 1.0,
                         arena_size=4.0 * seconds)   # room to roll straight at top speed
    env.reset(seed=seed)
    log = env.enable_signal_log()
    n = int(round(seconds * env.control_hz))
    for _ in range(n):
        env.step(np.array([drive, 0.0], dtype=np.float32))
    speed = float(np.linalg.norm(log[-1][2][:2]))
    samples = [s for *_, s in log if s is not None]
    env.close()
    t = np.array([s.t for s in samples])
    acc = np.array([s.acc for s in samples])
    keep = t >= 5.0
    return speed, acc[keep], 1.0 / float(np.median(np.diff(t)))


#: the robots of the estimator table: (label, realism, robot overrides)
ROBOTS = (("realistic", "real", None),
          ("no vibration", "real", {"vib_motor": 0.0, "vib_commutation": 0.0, "vib_gear": 0.0, "vib_seam": 0.0}),
          ("ideal", "ideal", None))
ESTIMATORS = (("ekf", {}), ("iir-ekf", {}), ("iir-ekf", {"cutoff_hz": 10.0}), ("ukf", {}))


def attitude_errors_straight(name, params, drive, seconds, realism, robot=None, seed=0):
    """rms inclination and heading error (deg) of ``name`` after the first 5 s."""
    from envs.sphere import SphereRobotEnv
    from fusion.metrics import attitude_errors
    env = SphereRobotEnv(task="track", estimator=name, estimator_params=params, realism=realism, robot=robot,
                         episode_s=seconds + 1.0, arena_size=4.0 * seconds)
    env.reset(seed=seed)
    qe, qt = [], []
    for k in range(int(round(seconds * env.control_hz))):
        _, _, _, _, info = env.step(np.array([drive, 0.0], dtype=np.float32))
        if k >= 5 * env.control_hz:
            qe.append(info["q_est"])
            qt.append(info["q_true"])
    env.close()
    e = attitude_errors(np.array(qe), np.array(qt))
    return float(np.sqrt(np.mean(e["inclination"] ** 2))), float(np.sqrt(np.mean(e["heading"] ** 2)))


def loop_tilt(episodes):
    from controllers import PID
    from controllers.evaluation import evaluate
    print(f"\nin the loop: PID, flat floor, seeds 0-{episodes - 1}, tilt_error mean (paired difference vs ekf "
          "+- its std), deg")
    for task in ("track", "waypoints"):
        for label, realism, robot in ROBOTS[:2]:
            res = {}
            for name, params in ESTIMATORS[:3]:
                kw = dict(task=task, estimator=name, estimator_params=params, realism=realism, robot=robot)
                eps = evaluate(PID(), kw, episodes=episodes, seed=0)["episodes"]
                res[name + "".join(f" {k}={v:g}" for k, v in params.items())] = np.array([e["tilt_error"] for e in eps])
            base = res["ekf"]
            print(f"{task:9s} {label:12s} " + "  ".join(
                f"{k} {v.mean():.3f} ({np.mean(v - base):+.3f} +- {np.std(v - base, ddof=1):.3f})"
                for k, v in res.items()), flush=True)


def bump_table():
    from envs import convergence as cv
    print("| run | IMU | largest peak 400 / 1600 Hz (m/s^2) | its difference | bump by bump: mean | worst "
          "| each bump |")
    print("|---|---|---|---|---|---|---|")
    for drive in (1.0, 0.6):
        for label, imu in (("ideal", "ideal"), ("MPU-9250 +-2 g", cv.mpu9250_16g(2)), ("+-4 g", cv.mpu9250_16g(4)),
                           ("+-8 g", cv.mpu9250_16g(8)), ("+-16 g", cv.mpu9250_16g(16))):
            a, b = cv.bump_agreement(drive, imu)
            r = a / b - 1.0
            print(f"| drive {drive:g}, {len(a)} bumps | {label} | {a.max():.1f} / {b.max():.1f} | "
                  f"{a.max() / b.max() - 1:+.1%} | {r.mean():+.1%} | {r[np.argmax(np.abs(r))]:+.1%} | "
                  f"{' '.join(f'{x:+.0%}' for x in r)} |", flush=True)


def main(argv=None):
    import fusion
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--drives", default="0.3,0.6,1.0")
    ap.add_argument("--drive-est", type=float, default=0.6)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--loop", type=int, default=0, metavar="N", help="also the in-loop check, N episodes per cell")
    ap.add_argument("--bumps", action="store_true", help="only each bump's peak at 400 and 1600 Hz, every range")
    a = ap.parse_args(argv)
    if a.bumps:
        bump_table()
        return
    print(f"{'robot':9s} {'drive':>5s} {'speed':>6s} {'std|acc|':>8s} {'std x/y/z (m/s^2)':>20s} "
          f"{'<fc':>5s} {'>fc':>5s}  strongest lines (Hz: amplitude m/s^2)")
    for realism in ("real", "ideal"):
        for drive in (float(x) for x in a.drives.split(",")):
            speed, acc, fs = measure(drive, a.seconds, realism)
            fc = fusion.make("iir-ekf", fs).cutoff_hz
            x = acc - acc.mean(axis=0)
            spec = np.abs(np.fft.rfft(x, axis=0)) ** 2
            f = np.fft.rfftfreq(len(x), 1.0 / fs)
            p = spec.sum(axis=1)
            p[0] = 0.0
            low, high = p[f < fc].sum() / p.sum(), p[f >= fc].sum() / p.sum()
            amp = 2.0 * np.sqrt(p) / len(x)          # a sine's amplitude, all axes together
            top = np.argsort(amp)[::-1][:4]
            lines = ", ".join(f"{f[i]:.1f}: {amp[i]:.2f}" for i in sorted(top, key=lambda i: f[i]))
            std = x.std(axis=0)
            print(f"{realism:9s} {drive:5.2f} {speed:6.3f} {np.linalg.norm(acc, axis=1).std():8.3f} "
                  f"{std[0]:6.3f}/{std[1]:6.3f}/{std[2]:6.3f} {low:5.2f} {high:5.2f}  {lines}")
    print(f"IMU rate {fs:.0f} Hz (Nyquist {fs / 2:.0f} Hz), iir-ekf cut-off {fc:.0f} Hz; "
          "<fc / >fc: shares of the fluctuation power below / above the cut-off")
    print(f"\nstraight at drive {a.drive_est}, {a.seconds:.0f} s, errors after 5 s, mean of {a.seeds} seeds "
          "(rms inclination / heading, deg)")
    print(f"{'estimator':24s}" + "".join(f" {label:>15s}" for label, *_ in ROBOTS))
    for name, params in ESTIMATORS:
        cols = []
        for _, realism, robot in ROBOTS:
            r = np.mean([attitude_errors_straight(name, params, a.drive_est, a.seconds, realism, robot, seed)
                         for seed in range(a.seeds)], axis=0)
            cols.append(f"{r[0]:6.3f} / {r[1]:6.3f}")
        label = name + "".join(f" {k}={v:g}" for k, v in params.items())
        print(f"{label:24s}" + "".join(f" {c:>15s}" for c in cols))
    if a.loop:
        loop_tilt(a.loop)


if __name__ == "__main__":
    main()
