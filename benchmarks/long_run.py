"""Long-run health of every estimator: --samples (default 1e8) samples at 1 kHz through each
estimator's `run`, chunk by chunk, from a realistic simulated sensor with fresh noise in
every chunk. At each checkpoint: the largest quaternion norm error so far, the covariance
symmetry error and smallest eigenvalue, the gyro-bias estimate and its error, and the
inclination error (truth known) at the checkpoint and the largest over the last chunk.

Sensor: the noise-free `mixed` scenario of fusion.scenarios (rotations with peaks of about
3 rad/s, linear-acceleration bursts), played forwards and then backwards (time-reversed
rates), so that the attitude path is seamless however long the run; noise densities and the
constant gyro bias of fusion.scenarios.DEFAULT_NOISE drawn afresh per chunk.

    nice -n 10 .venv/bin/python benchmarks/long_run.py [--samples 2e7] [--estimators ekf,ukf]

Writes results/benchmarks/long_run.md and long_run.csv (one row per estimator and checkpoint).
"""
import argparse
import csv
import os
import platform
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

import fusion
from fusion.scenarios import make_scenario, DEFAULT_NOISE

FS = 1000.0


def qmul(p, q):
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def inclination_deg(q, q_true):
    """Inclination part of the rotation between estimate and truth, degrees, per row."""
    e = qmul(q, q_true * np.array([1.0, -1.0, -1.0, -1.0]))
    return np.degrees(2 * np.arctan2(np.hypot(e[..., 1], e[..., 2]), np.hypot(e[..., 0], e[..., 3])))


def cycle(minutes, seed):
    """One seamless period: the ideal scenario forwards (samples 1..N-1) then backwards to
    sample 0. Returns gyr, acc, mag, q_true of length 2 (N - 1)."""
    sc = make_scenario("mixed", fs=FS, duration=60.0 * minutes, seed=seed, ideal=True)
    n = len(sc.t)
    fwd = np.arange(1, n)
    back = np.arange(n - 2, -1, -1)          # targets q[N-2] .. q[0]
    gyr = np.vstack([sc.omega[fwd], -sc.omega[back + 1]])
    acc = np.vstack([sc.acc[fwd], sc.acc[back]])
    mag = np.vstack([sc.mag[fwd], sc.mag[back]])
    q = np.vstack([sc.q_true[fwd], sc.q_true[back]])
    return gyr, acc, mag, q


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=float, default=1e8)
    ap.add_argument("--estimators", default=",".join(fusion.available()))
    ap.add_argument("--chunk", type=float, default=5e5, help="samples per run() call")
    ap.add_argument("--checkpoints", type=int, default=10)
    ap.add_argument("--minutes", type=float, default=3.0, help="length of the scenario played back and forth")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/benchmarks")
    a = ap.parse_args()
    total, chunk = int(a.samples), int(a.chunk)
    names = a.estimators.split(",")
    gyr0, acc0, mag0, q0 = cycle(a.minutes, a.seed)
    period = len(gyr0)
    bias = np.array(DEFAULT_NOISE["gyro_bias"])
    sd = {k: DEFAULT_NOISE[k] * np.sqrt(FS) for k in ("gyro_noise", "acc_noise", "mag_noise")}
    ests = {n: fusion.make(n, FS) for n in names}
    secs = dict.fromkeys(names, 0.0)
    norm_err = dict.fromkeys(names, 0.0)
    rows = []
    marks = set(np.linspace(0, total, a.checkpoints + 1).astype(np.int64)[1:].tolist())
    rng = np.random.default_rng(a.seed + 1)
    print(f"{platform.node()}: {os.cpu_count()} CPUs, {total:,} samples at {FS:g} Hz, "
          f"{period:,}-sample seamless cycle, chunks of {chunk:,}")
    done = 0
    with tqdm(total=total, unit="sample", unit_scale=True) as bar:
        while done < total:
            # the next chunk ends at a checkpoint or after `chunk` samples
            stop = min(min(m for m in marks if m > done), done + chunk)
            k = stop - done
            idx = np.arange(done, stop) % period
            gyr = gyr0[idx] + bias + sd["gyro_noise"] * rng.standard_normal((k, 3))
            acc = acc0[idx] + sd["acc_noise"] * rng.standard_normal((k, 3))
            mag = mag0[idx] + sd["mag_noise"] * rng.standard_normal((k, 3))
            for n, est in ests.items():
                t = time.perf_counter()
                q = est.run(gyr, acc, mag)
                secs[n] += time.perf_counter() - t
                norm_err[n] = max(norm_err[n], float(np.abs(np.linalg.norm(q, axis=1) - 1).max()))
                if stop in marks:
                    r = checkpoint_row(n, est, q, q0[idx], stop, norm_err[n], bias, secs[n])
                    rows.append(r)
                    tqdm.write(f"{n:9s} {stop:>12,d}  |q|-1 {r['norm_err']:.1e}  P-P' {r['sym_err']:.1e}  "
                               f"min eig {r['min_eig']:.2e}  |b| {r['bias_norm']:.5f}  "
                               f"b err {r['bias_err']:.1e}  incl {r['incl_deg']:.3f} deg "
                               f"(max {r['incl_max_chunk_deg']:.2f})  {r['ns_per_sample']:.0f} ns/sample")
            done = stop
            bar.update(k)
    write_outputs(Path(a.out), rows, total, a.samples)


def checkpoint_row(name, est, q, q_true, stop, norm_err, bias, secs):
    """The health figures of estimator ``est`` after ``stop`` samples (its last chunk ``q``)."""
    inc = inclination_deg(q, q_true)
    P = est.covariance
    b = est.bias
    return dict(
        estimator=name, samples=stop, hours=stop / FS / 3600,
        norm_err=norm_err,
        sym_err=np.nan if P is None else float(np.abs(P - P.T).max()),
        min_eig=np.nan if P is None else float(np.linalg.eigvalsh(0.5 * (P + P.T)).min()),
        bias_norm=np.nan if b is None else float(np.linalg.norm(b)),
        bias_err=np.nan if b is None else float(np.linalg.norm(b - bias)),
        incl_deg=float(inc[-1]), incl_max_chunk_deg=float(inc.max()),
        finite=bool(np.isfinite(q).all()),
        ns_per_sample=secs / stop * 1e9)


def write_outputs(out, rows, total, samples_arg):
    """long_run.csv (every checkpoint) and long_run.md (the last one) in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    cols = list(rows[0])
    with open(out / "long_run.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    final = [r for r in rows if r["samples"] == total]
    with open(out / "long_run.md", "w") as f:
        f.write(f"# Long run: {total:,} samples at {FS:g} Hz ({total / FS / 3600:.1f} h of data) per estimator\n\n")
        f.write(f"`benchmarks/long_run.py --samples {samples_arg:g}`; {os.cpu_count()} CPUs shared. "
                "Worst over the run for |q|-1; the rest at the last sample (incl max: over the last chunk). "
                "All checkpoints in long_run.csv.\n\n")
        f.write("| estimator | max abs(abs(q)-1) | max abs(P-P^T) | min eig P | abs(bias) | bias error | "
                "incl (deg) | incl max, last chunk (deg) | all finite | ns/sample |\n")
        f.write("|---|---|---|---|---|---|---|---|---|---|\n")
        for r in final:
            f.write(f"| {r['estimator']} | {r['norm_err']:.1e} | {r['sym_err']:.1e} | {r['min_eig']:.2e} | "
                    f"{r['bias_norm']:.5f} | {r['bias_err']:.1e} | {r['incl_deg']:.3f} | "
                    f"{r['incl_max_chunk_deg']:.2f} | {r['finite']} | {r['ns_per_sample']:.0f} |\n")
    print(f"wrote {out / 'long_run.md'} and {out / 'long_run.csv'}")


if __name__ == "__main__":
    main()
