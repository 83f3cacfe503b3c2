#!/usr/bin/env python
"""Throughput of our estimators and of peer libraries, in samples per second.

For every estimator in ``fusion.available()`` and, in the same run, for the peers
(vqf.VQF / vqf.BasicVQF, imufusion.Ahrs, ahrs.filters.Madgwick / Mahony / EKF), four modes:

- ``update 6-axis`` / ``update 9-axis``: one sample per call, called from a Python loop over
  the rows of (N, 3) float64 arrays (the rows are views; the loop itself is part of the cost,
  the same loop for everyone). For peers whose per-sample call returns nothing (VQF, imufusion)
  the loop also fetches the quaternion each sample (getQuat6D/getQuat9D, get_quaternion), so
  every row ends with the attitude in hand, as ``est.update`` does.
- ``run 6-axis`` / ``run 9-axis``: a whole recording in one call (``est.run``,
  ``VQF.updateBatch``, the ``ahrs`` batch constructors ``Madgwick(gyr=, acc=, mag=)``).
  imufusion has no batch API: its figure is its Python loop writing an (N, 4) array (marked †).

Data: the ``mixed`` synthetic scenario of ``fusion.scenarios`` (100 Hz, rotations up to about
3 rad/s plus linear-acceleration bursts), given to each library in its own units and frame:
ours, VQF, ahrs.Madgwick/Mahony rad/s and m/s^2 (specific force); imufusion deg/s and g
(convention ENU); ahrs.EKF rad/s and m/s^2 as gravity (minus the specific force), frame NED;
the magnetometer as 50 uT (VQF, imufusion: uT; ahrs: nT; ours: the scenario's unit).
The feeding of each library lives in benchmarks/peers.py, shared with accuracy.py.

Method: N is scaled per cell so one call takes about ``--target`` seconds (0.3 s), capped at
the 200,000 generated samples; one warm-up call per cell at that N, then 5 timed rounds
(time.perf_counter; ``--clock cpu``: the thread's CPU time, for a machine other jobs load),
each round timing every cell once (interleaved, so a slow spell of a shared machine hits every
method alike), each call on a freshly built estimator (construction
is not timed, except for the ahrs batch constructors, which are the batch call); the median of
the 5. Speed only: a quick sanity check (finite, unit-norm, moving quaternions that track the
true tilt) is printed first, not scored.

Bank section (same run, after the table): a bank of BANK_COUNT ``ekf`` (``fusion.make_bank``),
9-axis, the recording cut into BANK_COUNT consecutive pieces, one per filter: ``bank.update``
once per sample from a Python loop over the rows of (T, count, 3) arrays, against BANK_COUNT
separate ``ekf.update`` calls per sample (the same loop, one call per filter on the row's views),
``bank.run`` on the whole (T, count, 3) arrays against BANK_COUNT ``ekf.run`` calls (one per
filter's piece), and ``vqf.VQF.updateBatch`` over all T x count samples (the recording as one);
rates in filter-samples/s, the same interleaved rounds.

    .venv/bin/python benchmarks/throughput.py            # about 1.5-2 minutes
    .venv/bin/python benchmarks/throughput.py --quick    # under a minute
    .venv/bin/python benchmarks/throughput.py --out DIR  # default results/benchmarks/
    .venv/bin/python benchmarks/throughput.py --bank-only   # the bank section alone
    .venv/bin/python benchmarks/throughput.py --only fusion.ekf,vqf.VQF,vqf.BasicVQF --no-bank
                                                            # a few methods (ratios as in the full table)
"""
import argparse
import os
import platform
import statistics
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np

import fusion
from benchmarks.peers import Data, all_methods, sanity
from controllers.policy_io import check_writable, csv_text, write_text
from fusion.checks import arg_type, number


FS = 100.0
BANK_COUNT = 64
BANK_NAME = "ekf"
MODES = ("update 6-axis", "update 9-axis", "run 6-axis", "run 9-axis")
DAGGER = "†"                 # imufusion "run": its Python loop (no batch API)
# the clock of every timed call: wall time, or (--clock cpu) this thread's CPU time, which a
# machine shared with other jobs does not inflate while the benchmark waits for a core
CLOCKS = {"wall": time.perf_counter, "cpu": time.thread_time}
clock = CLOCKS["wall"]


# ---------------------------------------------------------------------------------------------
# timing

def _time_once(build, *args):
    """Seconds of one call of build(*args)'s returned closure (the build is not timed)."""
    go = build(*args)
    t0 = clock()
    go()
    return clock() - t0


def _nice(n):
    """n rounded down to two significant digits."""
    p = 10 ** max(int(np.floor(np.log10(max(n, 1)))) - 1, 0)
    return int(n // p * p)


def size_cell(method, kind, nine, d, n_max, target, n_min):
    """N for one cell, scaled so that one call takes about `target` s (at most n_max)."""
    builder = method.builders[kind]
    n = min(200, n_max)
    while True:                      # grow a probe until it takes a measurable time
        dt = _time_once(builder, d, n, nine)
        if dt >= target / 8 or n >= n_max:
            break
        n = min(n * 4, n_max)
    return max(min(_nice(n * target / max(dt, 1e-9)), n_max), min(n_min, n_max))


def measure_all(cells, d, repeats, log):
    """Median samples/s of every cell: (method, mode, kind, nine, n) -> result dict.

    One warm-up per cell, then `repeats` rounds, each timing every cell once: the repeats are
    interleaved across cells so that a slow spell of a shared machine hits all methods alike
    rather than all repeats of one of them."""
    times = {key: [] for key in cells}
    for meth, kind, nine, n in cells.values():
        _time_once(meth.builders[kind], d, n, nine)          # warm-up at the measured size
    for r in range(repeats):
        for key, (meth, kind, nine, n) in cells.items():
            times[key].append(_time_once(meth.builders[kind], d, n, nine))
        log(f"  round {r + 1}/{repeats} done")
    out = {}
    for key, (_, _, _, n) in cells.items():
        t = times[key]
        med = statistics.median(t)
        out[key] = dict(n=n, repeats=repeats, median_s=med, min_s=min(t), max_s=max(t), rate=n / med)
    return out


# ---------------------------------------------------------------------------------------------
# report

def fmt_rate(r):
    if r is None or not np.isfinite(r):
        return "–"
    for div, suf in ((1e6, " M"), (1e3, " k")):
        if r >= div:
            return f"{r / div:.3g}{suf}"
    return f"{r:.3g}"


def build_table(methods, results):
    """Rows of strings (Markdown) and of numbers (CSV)."""
    header = ["method"] + [f"{m} (samples/s)" for m in MODES]
    md_rows, csv_rows = [], []
    for meth in methods:
        cells, nums = [], []
        for mode in MODES:
            r = results.get((meth.name, mode))
            rate = r["rate"] if r else None
            mark = DAGGER if (meth.run_note and mode.startswith("run")) else ""
            cells.append(fmt_rate(rate) + mark)
            nums.append("" if rate is None else f"{rate:.6g}")
        md_rows.append([meth.name if meth.group == "peer" else f"**{meth.name}**"] + cells)
        csv_rows.append([meth.name, meth.group] + nums)

    peers = [m for m in methods if m.group == "peer"]
    best = {}
    for mode in MODES:
        cand = [(results[(p.name, mode)]["rate"], p.name) for p in peers if (p.name, mode) in results]
        best[mode] = max(cand) if cand else None
    md_rows.append(["best peer"] + [f"{b[1]} ({fmt_rate(b[0])})" if b else "–" for b in best.values()])
    csv_rows.append(["best peer", "peer"] + [b[1] if b else "" for b in best.values()])
    for meth in methods:
        if meth.group != "ours":
            continue
        cells, nums = [], []
        for mode in MODES:
            r, b = results.get((meth.name, mode)), best[mode]
            if r and b:
                ratio = r["rate"] / b[0]
                cells.append(f"{ratio:.2f}×")
                nums.append(f"{ratio:.4g}")
            else:
                cells.append("–")
                nums.append("")
        md_rows.append([f"{meth.name} / best peer"] + cells)
        csv_rows.append([f"{meth.name} / best peer", "ratio"] + nums)
    return header, md_rows, ["method", "group"] + list(MODES), csv_rows, best


def markdown(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" + "---:|" * (len(header) - 1)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def machine_info():
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return dict(platform=platform.platform(), python=platform.python_version(), cpu=cpu,
                cpu_count=os.cpu_count(), usable_cpus=usable)


def versions():
    out = {"fusion": getattr(fusion, "__version__", "?")}
    for dist in ("numpy", "vqf", "imufusion", "AHRS"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


# ---------------------------------------------------------------------------------------------
# bank section

class _Cell:
    """A timed cell for measure_all: builders["run"](d, n, nine) returns the callable."""

    def __init__(self, name, build):
        self.name, self.builders = name, {"run": build}


def bank_cells(d, n):
    """Cells over n = T * BANK_COUNT filter-samples of d (9-axis); VQF's only if it is installed
    (a peer, like those of benchmarks.peers.all_methods)."""
    try:
        import vqf
    except ImportError as e:
        print(f"skipping vqf in the bank section: {e}", flush=True)
        vqf = None
    c, T = BANK_COUNT, n // BANK_COUNT
    n = T * c

    def pieces(x):                    # filter i gets the recording's i-th piece of T samples
        return np.ascontiguousarray(x[:n].reshape(c, T, 3).transpose(1, 0, 2))

    G, A, M = pieces(d.gyr), pieces(d.acc), pieces(d.mag)

    def bank_update(d, n, nine):
        upd = fusion.make_bank(BANK_NAME, d.fs, c).update

        def go():
            for g, a, m in zip(G, A, M):
                q = upd(g, a, m)
            return q
        return go

    def separate_update(d, n, nine):
        upds = [fusion.make(BANK_NAME, d.fs).update for _ in range(c)]

        def go():
            for g, a, m in zip(G, A, M):
                q = [u(gi, ai, mi) for u, gi, ai, mi in zip(upds, g, a, m)]
            return q
        return go

    def bank_run(d, n, nine):
        b = fusion.make_bank(BANK_NAME, d.fs, c)
        return lambda: b.run(G, A, M)

    cols = [tuple(np.ascontiguousarray(x[:, i]) for x in (G, A, M)) for i in range(c)]

    def separate_run(d, n, nine):
        runs = [fusion.make(BANK_NAME, d.fs).run for _ in range(c)]
        return lambda: [r(*col) for r, col in zip(runs, cols)]

    def vqf_batch(d, n, nine):
        v = vqf.VQF(d.ts)
        g, a, m = d.gyr[:n], d.acc[:n], d.mag_ut[:n]
        return lambda: v.updateBatch(g, a, m)["quat9D"]

    names = {"bank update": (f"bank of {c} {BANK_NAME}: bank.update per sample", bank_update),
             "separate update": (f"{c} x {BANK_NAME}.update per sample", separate_update),
             "bank run": (f"bank of {c} {BANK_NAME}: bank.run", bank_run),
             "separate run": (f"{c} x {BANK_NAME}.run, one per filter's piece", separate_run)}
    if vqf is not None:
        names["vqf batch"] = ("vqf.VQF.updateBatch over all samples", vqf_batch)
    return {key: (_Cell(label, build), "run", True, n) for key, (label, build) in names.items()}


def bank_section(d, n, repeats):
    """Time the bank cells (interleaved rounds); the report's lines."""
    print(f"\nbank section: {BANK_COUNT} {BANK_NAME}, 9-axis, {n // BANK_COUNT:,} samples per filter "
          f"({n // BANK_COUNT * BANK_COUNT:,} filter-samples per call), {repeats} interleaved rounds:", flush=True)
    cells = bank_cells(d, n)
    res = measure_all(cells, d, repeats, lambda msg: print(msg, flush=True))
    rate = {k: r["rate"] for k, r in res.items()}
    lines = ["| method | filter-samples/s |", "|---|---:|"]
    lines += [f"| {cells[k][0].name} | {fmt_rate(rate[k])} |" for k in cells]
    vqf = "vqf batch" in rate
    lines += ["",
              f"- bank.update / {BANK_COUNT} separate update calls: "
              f"{rate['bank update'] / rate['separate update']:.2f}x (target >= 4x)"]
    if vqf:
        lines.append(f"- bank.update time per filter-sample / VQF updateBatch time per sample: "
                     f"{rate['vqf batch'] / rate['bank update']:.2f} (target <= 1)")
    lines.append(f"- bank.run / {BANK_NAME}.run per piece: {rate['bank run'] / rate['separate run']:.2f}x"
                 + (f"; bank.run / VQF updateBatch: {rate['bank run'] / rate['vqf batch']:.2f}x" if vqf else ""))
    return "\n".join(lines), res


def sanity_all(methods, d, n_sanity):
    """(method name, mode) -> (ok, tilt error deg) of every cell, printed as a table."""
    print("sanity (tilt error vs truth, deg; update: last sample, run: median of 2nd half; "
          f"first {n_sanity} samples):")
    sane = {}
    for meth in methods:
        cells = []
        for mode in MODES:
            kind, nine = mode.split()[0], mode.endswith("9-axis")
            try:
                ok, err = sanity(meth, kind, nine, d, n_sanity)
            except Exception as e:                                     # noqa: BLE001
                ok, err = False, float("nan")
                print(f"  {meth.name} {mode}: {type(e).__name__}: {e}")
            sane[(meth.name, mode)] = (ok, err)
            cells.append(f"{mode} {err:6.2f}{'' if ok else ' CHECK'}")
        print(f"  {meth.name:<22s} " + " | ".join(cells)
              + ("  (gyro integration only: drifts by design)" if meth.drifts else ""), flush=True)
    print()
    return sane


def size_all(methods, d, n_run, n_upd, target, n_min):
    """(method name, mode) -> (method, kind, nine, N) of every cell that could be sized."""
    print(f"sizing (N per cell for ~{target:g} s per call):", flush=True)
    cells = {}
    for meth in methods:
        sizes = []
        for mode in MODES:
            kind, nine = mode.split()[0], mode.endswith("9-axis")
            n_max = n_run if kind == "run" else n_upd
            try:
                n = size_cell(meth, kind, nine, d, n_max, target, n_min)
            except Exception as e:                                     # noqa: BLE001
                print(f"  {meth.name} {mode}: failed: {type(e).__name__}: {e}")
                continue
            cells[(meth.name, mode)] = (meth, kind, nine, n)
            sizes.append(f"{mode} N={n:,}")
        print(f"  {meth.name:<22s} " + " | ".join(sizes), flush=True)
    return cells


def detail_rows(results, cells, sane):
    """The rows of throughput_detail.csv: every cell's timings and sanity."""
    detail = []
    for (name, mode), r in results.items():
        meth, kind = cells[(name, mode)][0], cells[(name, mode)][1]
        ok, err = sane[(name, mode)]
        detail.append(dict(method=name, group=meth.group, mode=mode,
                           note=meth.run_note if kind == "run" else "",
                           sanity_ok=ok, tilt_err_deg=f"{err:.3g}",
                           n=r["n"], repeats=r["repeats"], median_s=f"{r['median_s']:.6g}",
                           min_s=f"{r['min_s']:.6g}", max_s=f"{r['max_s']:.6g}",
                           samples_per_s=f"{r['rate']:.6g}",
                           spread_max_over_min=f"{r['max_s'] / r['min_s']:.3g}"))
    return detail


def write_outputs(out, md, csv_header, csv_rows, detail):
    """throughput.md (``md`` under its title), throughput.csv and throughput_detail.csv in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    md_path, csv_path, det_path = out / "throughput.md", out / "throughput.csv", out / "throughput_detail.csv"
    write_text(md_path, "# Estimator throughput (samples/s)\n\n" + md)
    write_text(csv_path, csv_text([dict(zip(csv_header, r)) for r in csv_rows], csv_header))
    write_text(det_path, csv_text(detail, list(detail[0]) if detail else ["method"]))
    print(f"wrote {md_path}\nwrote {csv_path}\nwrote {det_path}")


def select_methods(methods, only):
    """The methods named in ``only`` (comma-separated; None: all)."""
    if not only:
        return methods
    keep = set(only.split(","))
    unknown = keep - {m.name for m in methods}
    if unknown:
        raise ValueError(f"--only: unknown method(s) {sorted(unknown)}; known: {[m.name for m in methods]}")
    return [m for m in methods if m.name in keep]


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog="spherebot-bench", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="fewer samples and repeats (whole script under about a minute)")
    ap.add_argument("--out", default=os.path.join("results", "benchmarks"),
                    help="output folder for throughput.md / throughput.csv (default: %(default)s)")
    ap.add_argument("--target", type=arg_type(number, low=0.0, high=60.0, open_low=True), default=None,
                    help="seconds per measurement used to scale N (default 0.3, quick 0.06)")
    bank = ap.add_mutually_exclusive_group()
    bank.add_argument("--bank-only", action="store_true", help="only the bank section (printed; no files)")
    ap.add_argument("--only", default=None,
                    help="comma-separated method names to time (e.g. fusion.ekf,vqf.VQF); default: all")
    bank.add_argument("--no-bank", action="store_true", help="skip the bank section")
    ap.add_argument("--clock", choices=tuple(CLOCKS), default="wall",
                    help="wall time (default) or this thread's CPU time (for a loaded machine)")
    return ap.parse_args(argv)


def _check_before_timing(args):
    """Where the tables go and the --only names, before any timing: an error exits."""
    try:
        if not args.bank_only:
            check_writable(args.out)
            select_methods(all_methods(lambda *a: None), args.only)
    except ValueError as e:
        sys.exit(f"error: {e}")


def main(argv=None):
    args = parse_args(argv)
    global clock
    clock = CLOCKS[args.clock]

    n_run, n_upd, repeats, target, n_min, n_sanity = ((50_000, 50_000, 3, 0.06, 200, 1500) if args.quick
                                                      else (200_000, 200_000, 5, 0.3, 500, 3000))
    target = target if args.target is None else args.target
    _check_before_timing(args)

    t_start = time.perf_counter()
    info, vers = machine_info(), versions()
    print("# Estimator throughput (samples/s)\n")
    print(f"machine: {info['platform']}, Python {info['python']}")
    print(f"cpu: {info['cpu']}; {info['cpu_count']} CPUs ({info['usable_cpus']} usable); "
          f"single-threaded measurements")
    print("versions: " + ", ".join(f"{k} {v}" for k, v in vers.items()))
    print(f"settings: {'quick' if args.quick else 'default'}; fs {FS:g} Hz; N <= {n_run:,} (run), "
          f"<= {n_upd:,} (update), scaled to ~{target:g} s per measurement; "
          f"median of {repeats} after 1 warm-up; {args.clock} clock\n", flush=True)

    d = Data.mixed(max(n_run, n_upd, n_sanity), fs=FS)
    n_bank = n_run if not args.quick else 48_000
    if args.bank_only:
        text, _ = bank_section(d, n_bank, repeats)
        print("\n" + text)
        print(f"total {time.perf_counter() - t_start:.0f} s")
        return
    methods = select_methods(all_methods(print), args.only)

    sane = sanity_all(methods, d, n_sanity)         # first: also imports and warms every code path
    cells = size_all(methods, d, n_run, n_upd, target, n_min)
    print(f"timing ({repeats} interleaved rounds after 1 warm-up per cell):", flush=True)
    results = measure_all(cells, d, repeats, lambda msg: print(msg, flush=True))
    detail = detail_rows(results, cells, sane)

    header, md_rows, csv_header, csv_rows, best = build_table(methods, results)
    table = markdown(header, md_rows)
    notes = (f"{DAGGER} imufusion has no batch API: its run figure is its Python loop writing an (N, 4) array.\n"
             "update = one call per sample from a Python loop over array rows (VQF and imufusion also fetch "
             "the quaternion each sample); run = one batch call. Ratios: ours / fastest peer in that column. "
             "Median of %d repeats; N per cell in throughput_detail.csv." % repeats)
    print("\n" + table + "\n\n" + notes + "\n")
    bank_text = "(skipped: --no-bank)"
    if not args.no_bank:
        bank_text, _ = bank_section(d, n_bank, repeats)
        print("\n" + bank_text + "\n")

    head = (f"- machine: {info['platform']}, Python {info['python']}; cpu: {info['cpu']}; "
            f"{info['cpu_count']} CPUs ({info['usable_cpus']} usable)\n"
            "- versions: " + ", ".join(f"{k} {v}" for k, v in vers.items()) + "\n"
            f"- settings: {'quick' if args.quick else 'default'}; fs {FS:g} Hz; "
            f"N <= {n_run:,} (run), <= {n_upd:,} (update), ~{target:g} s per measurement; "
            f"{args.clock} clock\n\n")
    md = head + table + "\n\n" + notes + "\n" + "\n## Bank\n\n" + bank_text + "\n"
    write_outputs(Path(args.out), md, csv_header, csv_rows, detail)
    print(f"total {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    sys.exit(main())
