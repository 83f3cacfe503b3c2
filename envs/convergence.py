"""The physics-rate convergence check behind the default ``physics_hz`` (docs/envs/robot.md,
"Rates"): the hardest inputs of the action space, run at a rate and at 4x that rate, with
the ideal IMU and the true attitude (so that only the physics differs).

    python -m envs.convergence            # prints the table at 400 vs 1600 Hz
"""
import math
import sys

import numpy as np

from envs.track import SphereBotTrackEnv
from fusion.constants import GRAVITY

#: name -> action(t) for t in s; 10 s each
SCENARIOS = {
    "full drive + full steer": lambda t: (1.0, 0.0 if t < 2.0 else 1.0),
    "full drive, half steer from 4 s": lambda t: (1.0, 0.0 if t < 4.0 else 0.5),
    "bang-bang steer 0.8 s": lambda t: (1.0, 1.0 if int(t / 0.8) % 2 else -1.0),
    "reversals every 1 s, steer 0.5": lambda t: (1.0 if int(t) % 2 == 0 else -1.0, 0.5),
    "hard turn then release": lambda t: (1.0, 1.0 if 1.0 < t < 4.0 else 0.0),
    "bumps every 1 m, full drive": lambda t: (1.0, 0.0),
    "bumps every 1 m, 0.6 drive": lambda t: (0.6, 0.0),
}
DURATION_S = 10.0


class _Env(SphereBotTrackEnv):
    """The bumps (if any) across the path: 1.2 cm capsules at x = 1, 2, ... m."""

    def _draw_layout(self, start=None):
        xy, yaw, bumps, ramps = super()._draw_layout(start)
        return xy, yaw, [(1.0 + i, 0.0, 0.0) for i in range(len(bumps))], ramps


def mpu9250_16g(g_range=16):
    """The calibrated MPU-9250 preset at its +-``g_range`` g range (2, 4, 8 or 16: ACCEL_FS_SEL
    0-3, 16384 / g_range LSB per g): its 2 g default saturates on a bump. Its DLPF (218.1 Hz
    accelerometer, 250 Hz gyro) smooths the impact before the output register."""
    from dataclasses import replace
    from fusion import imu as fimu
    spec = fimu.preset("mpu9250", calibrated=True)
    return spec.replace(acc=replace(spec.acc, range=g_range * fimu.G0, lsb=fimu.G0 * g_range / 32768.0))


def bump_peaks(physics_hz, drive=1.0, imu="ideal", seed=0, bumps=8):
    """Each bump's peak |acc| - g (m/s^2) at the IMU, straight over ``bumps`` bumps at x = 1, 2,
    ... m (the samples within 0.5 m of each), at ``drive`` of full voltage."""
    env = _Env(estimator="truth", imu=imu, physics_hz=physics_hz, episode_s=DURATION_S + 1.0, arena_size=60.0,
               bumps=bumps)
    env.reset(seed=seed, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
    log = env.enable_signal_log()
    for _ in range(int(DURATION_S * env.control_hz)):
        env.step((drive, 0.0))
    env.close()
    x = np.array([pos[0] for pos, *_, s in log if s is not None])
    an = np.abs(np.linalg.norm(np.array([s.acc for *_, s in log if s is not None]), axis=1) - GRAVITY)
    out = []
    for k in range(1, bumps + 1):
        near = np.abs(x - k) < 0.5
        if near.any():
            out.append(float(an[near].max()))
    return np.array(out)


def bump_agreement(drive=1.0, imu="ideal", hz=400.0, factor=4):
    """Each bump's peak (``bump_peaks``) at ``hz`` and at ``factor`` x ``hz``, for the bumps both
    runs crossed (a bump not reached in the run reads about 1 m/s^2)."""
    a, b = bump_peaks(hz, drive, imu), bump_peaks(hz * factor, drive, imu)
    n = min(len(a), len(b))
    crossed = (a[:n] > 5.0) & (b[:n] > 5.0)
    return a[:n][crossed], b[:n][crossed]


def run(name, physics_hz, seed=0, imu="ideal"):
    """Final position (m), heading (rad), roll peak to peak over the last 2 s (deg), and the
    ideal IMU's |acc| std, gyro-norm std and peak |acc - g| over the run."""
    act = SCENARIOS[name]
    bumps = 8 if name.startswith("bumps") else 0
    env = _Env(estimator="truth", imu=imu, physics_hz=physics_hz, episode_s=DURATION_S + 1.0, arena_size=60.0,
               bumps=bumps)
    env.reset(seed=seed, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
    log = env.enable_signal_log()
    rolls = []
    n = int(DURATION_S * env.control_hz)
    for k in range(n):
        if env.step(act(k / env.control_hz))[2]:
            raise RuntimeError(f"scenario {name!r} ended early at {physics_hz:g} Hz")
        R = env.true_state()["rotation"]
        rolls.append(math.degrees(math.asin(max(-1.0, min(1.0, R[2, 1])))))
    acc = np.array([s.acc for *_, s in log if s is not None])
    gyr = np.array([s.gyr for *_, s in log if s is not None])
    st = env.true_state()
    env.close()
    r = np.array(rolls[-int(2 * 50):])
    an = np.linalg.norm(acc, axis=1)
    return {"position": st["position"][:2].copy(), "heading": math.atan2(-st["rotation"][0, 1], st["rotation"][1, 1]),
            "roll_pp_deg": float(np.ptp(r)), "acc_std": float(an.std()),
            "gyr_std": float(np.linalg.norm(gyr, axis=1).std()),
            "acc_peak": float(np.abs(an - GRAVITY).max())}


#: s: the ends of the 2-s windows whose roll peak to peak rocking_decay fits
ROCK_WINDOWS = (6, 10, 14, 18, 22)


def rocking_decay(physics_hz, realism="real"):
    """Decay rate (1/s) of the sideways rocking after a hard turn (full drive, full steer from
    1 to 4 s, then straight): the slope of log(roll peak to peak) over the 2-s windows ending
    at ROCK_WINDOWS. A rate, not a roll difference in degrees: PyBullet's multibody step adds
    energy to the rocking in proportion to the step (docs/envs/robot.md, "Rates"), which an
    absolute tolerance of a few degrees on a decayed roll does not see."""
    env = _Env(estimator="truth", imu="ideal", physics_hz=physics_hz, episode_s=ROCK_WINDOWS[-1] + 1.0,
               arena_size=60.0, realism=realism)
    env.reset(seed=0, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
    rolls = []
    for k in range(int(ROCK_WINDOWS[-1] * env.control_hz)):
        env.step(SCENARIOS["hard turn then release"](k / env.control_hz))
        R = env.true_state()["rotation"]
        rolls.append(math.degrees(math.asin(max(-1.0, min(1.0, R[2, 1])))))
    env.close()
    n = int(env.control_hz)
    pp = [np.ptp(rolls[(e - 2) * n:e * n]) for e in ROCK_WINDOWS]
    return float(-np.polyfit(ROCK_WINDOWS, np.log(pp), 1)[0])


def compare(name, hz=400.0, factor=4):
    a, b = run(name, hz), run(name, hz * factor)
    peak = None
    if name.startswith("bumps"):
        peak = (run(name, hz, imu=mpu9250_16g())["acc_peak"], run(name, hz * factor, imu=mpu9250_16g())["acc_peak"])
    dpos = float(np.linalg.norm(a["position"] - b["position"]))
    dpsi = math.degrees(abs((a["heading"] - b["heading"] + math.pi) % (2 * math.pi) - math.pi))
    return {"dpos_m": dpos, "dheading_deg": dpsi, "roll_pp": (a["roll_pp_deg"], b["roll_pp_deg"]),
            "acc_std": (a["acc_std"], b["acc_std"]), "gyr_std": (a["gyr_std"], b["gyr_std"]),
            "acc_peak": (a["acc_peak"], b["acc_peak"]), "mpu_peak": peak}


def main(hz=400.0):
    print(f"physics {hz:g} Hz against {4 * hz:g} Hz, {DURATION_S:g} s each, ideal IMU, true attitude")
    print("| scenario | Δ position (m) | Δ heading (°) | roll p-p last 2 s (°) | IMU ‖acc‖ std (m/s²) "
          "| IMU ‖gyr‖ std (rad/s) | peak ‖acc‖−g (m/s²) | MPU-9250 ±16 g peak (m/s²) |")
    print("|---|---|---|---|---|---|---|---|")
    for name in SCENARIOS:
        c = compare(name, hz)
        f = lambda p: f"{p[0]:.3g} / {p[1]:.3g}"   # noqa: E731
        print(f"| {name} | {c['dpos_m']:.3f} | {c['dheading_deg']:.2f} | {f(c['roll_pp'])} | {f(c['acc_std'])} "
              f"| {f(c['gyr_std'])} | {f(c['acc_peak'])} | {f(c['mpu_peak']) if c['mpu_peak'] else ''} |", flush=True)
    rates = {h: rocking_decay(h) for h in (hz, 2 * hz, 4 * hz, 8 * hz)}
    print("rocking decay rate after a hard turn (1/s): "
          + ", ".join(f"{r:.4f} at {h:g} Hz" for h, r in rates.items()))


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 400.0)
