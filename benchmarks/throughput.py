#!/usr/bin/env python
"""Samples per second of every estimator of ours and of the peers (vqf, imufusion, ahrs),
measured side by side in one run: `update` per call from a Python loop and `run` (batch),
6-axis and 9-axis. Median of 5 repeats after a warm-up. Writes Markdown + CSV.

    python benchmarks/throughput.py [--quick] [--out results/benchmarks]

imufusion has no batch call: its "run" figure is its Python loop (said in the table). ahrs
filters are pure Python: their batch constructors are timed on fewer samples.
"""
import argparse
import csv
import os
import platform
import time
from pathlib import Path

import numpy as np

import fusion

MODES = ("update 6-axis", "update 9-axis", "run 6-axis", "run 9-axis")


def signals(n, fs=100.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    gyr = 0.5 * np.column_stack([np.sin(0.7 * t), np.cos(0.3 * t), np.sin(0.2 * t)]) + rng.normal(0, 0.01, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.2, (n, 3))
    mag = np.array([0.0, 20.0, -40.0]) + rng.normal(0, 0.5, (n, 3))
    return gyr, acc, mag


def median_rate(fn, n, repeats):
    fn()                                   # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return n / float(np.median(times))


def ours(name, fs, g, a, m, n_call, repeats):
    est = fusion.make(name, fs)

    def loop(mag):
        def f():
            est.reset()
            upd = est.update
            if mag is None:
                for i in range(n_call):
                    upd(g[i], a[i])
            else:
                for i in range(n_call):
                    upd(g[i], a[i], m[i])
        return f

    def batch(mag):
        def f():
            est.reset()
            est.run(g, a, mag)
        return f

    return {"update 6-axis": median_rate(loop(None), n_call, repeats),
            "update 9-axis": median_rate(loop(m), n_call, repeats),
            "run 6-axis": median_rate(batch(None), len(g), repeats),
            "run 9-axis": median_rate(batch(m), len(g), repeats)}


def peers(fs, g, a, m, n_call, n_py, repeats):
    rows = {}
    dt = 1.0 / fs
    try:
        import vqf
        gc, ac, mc = (np.ascontiguousarray(x) for x in (g, a, m))
        r = {}
        for label, mag in (("6-axis", None), ("9-axis", mc)):
            def batch(mag=mag):
                vqf.VQF(dt).updateBatch(gc, ac, mag)

            def loop(mag=mag):
                v = vqf.VQF(dt)
                for i in range(n_call):
                    if mag is None:
                        v.update(gc[i], ac[i])
                    else:
                        v.update(gc[i], ac[i], mag[i])
            r["run " + label] = median_rate(batch, len(g), repeats)
            r["update " + label] = median_rate(loop, n_call, repeats)
        rows["vqf.VQF"] = r
    except ImportError:
        print("vqf not installed: pip install '.[bench]'")
    try:
        import imufusion
        gd, ag = np.degrees(g), a / 9.81
        r = {}
        for label, use_mag in (("6-axis", False), ("9-axis", True)):
            def loop(use_mag=use_mag):
                ahrs = imufusion.Ahrs()
                ahrs.set_sample_period(dt)
                for i in range(n_call):
                    if use_mag:
                        ahrs.update(gd[i], ag[i], m[i])
                    else:
                        ahrs.update_no_magnetometer(gd[i], ag[i])
            rate = median_rate(loop, n_call, repeats)
            r["update " + label] = rate
            r["run " + label] = rate          # no batch API: its Python loop
        rows["imufusion.Ahrs (no batch: loop)"] = r
    except ImportError:
        print("imufusion not installed")
    try:
        from ahrs.filters import EKF, Madgwick, Mahony
        for cls in (Madgwick, Mahony, EKF):
            r = {}
            for label, mag in (("6-axis", None), ("9-axis", m)):
                kw = dict(gyr=g[:n_py], acc=a[:n_py], frequency=fs)
                if mag is not None:
                    kw["mag"] = mag[:n_py]
                r["run " + label] = median_rate(lambda kw=kw: cls(**kw), n_py, max(1, repeats // 2))
            rows[f"ahrs.{cls.__name__}"] = r
    except ImportError:
        print("ahrs not installed")
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer samples and repeats (< 1 min)")
    p.add_argument("--out", default="results/benchmarks")
    args = p.parse_args(argv)
    n_batch, n_call, n_py, repeats = (50_000, 5_000, 500, 3) if args.quick else (200_000, 20_000, 2_000, 5)
    fs = 100.0
    g, a, m = signals(n_batch, fs)
    import importlib.metadata as md
    vers = {}
    for pkg in ("numpy", "vqf", "imufusion", "ahrs"):
        try:
            vers[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            vers[pkg] = "absent"
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}; "
          + ", ".join(f"{k} {v}" for k, v in vers.items()))
    print(f"samples: batch {n_batch}, per call {n_call}, ahrs {n_py}; median of {repeats}")
    rows = {}
    for name in fusion.available():
        rows[name] = ours(name, fs, g, a, m, n_call, repeats)
        print(f"  measured {name}")
    peer_rows = peers(fs, g, a, m, n_call, n_py, repeats)
    rows.update(peer_rows)
    best = {mode: max((r[mode] for k, r in peer_rows.items() if mode in r), default=float("nan"))
            for mode in MODES}
    header = ["method"] + [f"{mode} (samples/s)" for mode in MODES]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    table = []
    for k, r in rows.items():
        vals = [r.get(mode, float("nan")) for mode in MODES]
        table.append([k] + vals)
        lines.append("| " + k + " | " + " | ".join("-" if not np.isfinite(v) else f"{v:,.0f}" for v in vals) + " |")
    lines.append("| **best peer** | " + " | ".join(f"{best[mode]:,.0f}" for mode in MODES) + " |")
    for name in fusion.available():
        ratios = [rows[name][mode] / best[mode] for mode in MODES]
        table.append([f"{name} / best peer"] + ratios)
        lines.append(f"| {name} / best peer | " + " | ".join(f"{x:.2f}x" for x in ratios) + " |")
    md_text = "\n".join(lines)
    print(md_text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "throughput.md").write_text(md_text + "\n")
    with open(out / "throughput.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["method"] + list(MODES))
        w.writerows(table)
    print(f"wrote {out / 'throughput.md'} and {out / 'throughput.csv'}")


if __name__ == "__main__":
    main()
