#!/usr/bin/env python
"""Check that a wheel's compiled kernels use no instruction beyond the ISA its tag promises.

A wheel tagged ``linux_x86_64`` / ``manylinux_*_x86_64`` must run on every x86-64 CPU, i.e.
the baseline (SSE2) instruction set: no SSE3/SSSE3/SSE4, POPCNT, BMI, AVX, AVX2, FMA or
AVX-512 (no VEX/EVEX-encoded ``v*`` mnemonics, no ymm/zmm/k registers). A ``*_aarch64`` wheel
must run on every ARMv8.0-A CPU: no SVE (z/p registers), LSE atomics, dot product, complex
or bfloat16 arithmetic, or the optional CRC32 / crypto instructions; LSE atomics are allowed
in libgcc's outline-atomic helpers (``__aarch64_*``), which choose them at run time, but a
stripped file has lost those names: setup.py builds aarch64 with -mno-outline-atomics.

Each ``.so`` is disassembled with ``objdump -d``; every offending instruction is counted per
mnemonic and printed with its function. The wheel is also checked for what it must not ship
(generated ``.c``, ``.pyx`` sources, unstripped symbol tables or debug sections) and its size
is printed (the limit: 3 MB). Exit status 0: all clean; 1: a finding.

    python benchmarks/check_wheel_isa.py dist/*.whl     # wheels built by `python -m build`
    python benchmarks/check_wheel_isa.py --build        # build one first (python -m build --wheel)
    python benchmarks/check_wheel_isa.py --installed    # the importable fusion package's .so
    python benchmarks/check_wheel_isa.py --so aarch64 _ekf.so   # one file (a cross objdump for aarch64)
"""
import argparse
import collections
import importlib.util
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

# the kernels take about 2 MB; the shipped policies (controllers/policies, 78 files) 1.3 MB more
MAX_WHEEL_BYTES = 4_000_000

# x86-64 baseline = SSE2. Instructions of the later extensions that are not VEX-encoded:
_X86_LATER = {
    # SSE3
    "addsubpd", "addsubps", "haddpd", "haddps", "hsubpd", "hsubps", "lddqu", "movddup",
    "movshdup", "movsldup", "fisttp", "fisttps", "fisttpl", "fisttpll", "monitor", "mwait",
    # SSSE3
    "pshufb", "phaddw", "phaddd", "phaddsw", "phsubw", "phsubd", "phsubsw", "pmaddubsw",
    "pmulhrsw", "palignr", "psignb", "psignw", "psignd", "pabsb", "pabsw", "pabsd",
    # SSE4.1
    "blendpd", "blendps", "blendvpd", "blendvps", "dppd", "dpps", "extractps", "insertps",
    "movntdqa", "mpsadbw", "packusdw", "pblendvb", "pblendw", "pcmpeqq", "pextrb", "pextrd",
    "pextrq", "phminposuw", "pinsrb", "pinsrd", "pinsrq", "pmaxsb", "pmaxsd", "pmaxud",
    "pmaxuw", "pminsb", "pminsd", "pminud", "pminuw", "pmuldq", "pmulld", "ptest", "roundpd",
    "roundps", "roundsd", "roundss",
    # SSE4.2, POPCNT, LZCNT, BMI1/2, MOVBE, ADX
    "crc32", "crc32b", "crc32w", "crc32l", "crc32q", "pcmpestri", "pcmpestrm", "pcmpistri",
    "pcmpistrm", "pcmpgtq", "popcnt", "lzcnt", "andn", "bextr", "blsi", "blsmsk", "blsr",
    "bzhi", "mulx", "pdep", "pext", "rorx", "sarx", "shlx", "shrx", "movbe", "adcx", "adox",
}
_X86_LATER_PREFIX = ("pmovsx", "pmovzx")
# VEX/EVEX (AVX, AVX2, FMA, F16C, AVX-512) mnemonics all start with "v"; these do not
_X86_V_BASELINE = {"verr", "verw"}
_X86_LATER_REG = re.compile(r"%(?:ymm|zmm)\d+|%xmm(?:1[6-9]|2\d|3[01])\b|\{%k[0-7]\}|%k[0-7]\b")

# AArch64 baseline = ARMv8.0-A with FP and Advanced SIMD (NEON)
_A64_LATER_PREFIX = (
    # LSE atomics (ARMv8.1)
    "ldadd", "ldclr", "ldeor", "ldset", "ldsmax", "ldsmin", "ldumax", "ldumin", "stadd", "stclr",
    "steor", "stset", "stsmax", "stsmin", "stumax", "stumin", "swp", "cas",
    # dot product, int8 / bfloat16 matrix, complex, JavaScript convert, FRINT32/64, RCpc
    "sdot", "udot", "usdot", "sudot", "smmla", "ummla", "usmmla", "bfdot", "bfmmla", "bfmlal",
    "bfcvt", "fcmla", "fcadd", "fjcvtzs", "frint32", "frint64", "ldapr",
    # optional in ARMv8.0: CRC32, AES, SHA, PMULL
    "crc32", "aes", "sha1", "sha256", "sha512", "sha3", "pmull", "eor3", "rax1", "xar", "bcax",
)
_A64_LATER_REG = re.compile(r"\bz\d+\.[bhsdq]\b|\bp\d+/[mz]\b|\bp\d+\.[bhsd]\b")
_A64_RUNTIME_DISPATCHED = re.compile(r"^__aarch64_")

_INSN = re.compile(r"^\s*[0-9a-f]+:\s+(?:[0-9a-f]{2} )*\s*(\S+)\s*(.*)$")
_FUNC = re.compile(r"^[0-9a-f]+ <(.+)>:$")


def offending(arch, mnemonic, operands, func):
    """The reason `mnemonic operands` (in function `func`) is beyond arch's baseline, or None."""
    m = mnemonic.lower()
    if arch == "x86_64":
        for prefix in ("rep", "repz", "repnz", "lock", "notrack", "bnd", "data16", "addr32", "cs", "ds"):
            if m == prefix and operands:          # objdump prints some prefixes as words
                m = operands.split()[0].lower()
                operands = operands[len(m):]
        if m.startswith("v") and m not in _X86_V_BASELINE:
            return "AVX/AVX2/FMA/AVX-512 (VEX/EVEX)"
        if m in _X86_LATER or m.startswith(_X86_LATER_PREFIX):
            return "SSE3+/BMI/POPCNT"
        if _X86_LATER_REG.search(operands):
            return "ymm/zmm/k register"
        return None
    if arch == "aarch64":
        if _A64_RUNTIME_DISPATCHED.match(func):
            return None
        if m.startswith(_A64_LATER_PREFIX):
            return "beyond ARMv8.0-A"
        if _A64_LATER_REG.search(operands):
            return "SVE register"
        return None
    raise ValueError(f"arch: {arch!r} has no rules; known: x86_64, aarch64")


def check_so(path, arch, objdump="objdump"):
    """Disassemble one shared object; returns ({(reason, mnemonic): [functions]}, notes)."""
    out = subprocess.run([objdump, "-d", "--no-show-raw-insn", str(path)], check=True,
                         capture_output=True, text=True).stdout
    found = collections.defaultdict(list)
    func = ""
    n = 0
    for line in out.splitlines():
        f = _FUNC.match(line)
        if f:
            func = f.group(1)
            continue
        i = _INSN.match(line)
        if not i or i.group(1).startswith("(bad)") or i.group(1).endswith(">:"):
            continue
        n += 1
        why = offending(arch, i.group(1), i.group(2), func)
        if why:
            found[(why, i.group(1))].append(func)
    headers = subprocess.run([objdump, "-h", "-t", str(path)], check=True, capture_output=True,
                             text=True).stdout
    notes = []
    if ".debug_" in headers:
        notes.append("debug sections present (not built with -g0)")
    symtab = headers.split("SYMBOL TABLE:", 1)[1].strip() if "SYMBOL TABLE:" in headers else ""
    if symtab and not symtab.startswith("no symbols"):
        notes.append("symbol table not stripped")
    return found, notes, n


def arch_of_wheel(name):
    for arch in ("x86_64", "aarch64"):
        if name.endswith(f"{arch}.whl") or f"_{arch}." in name:
            return arch
    raise ValueError(f"{name}: no x86_64 or aarch64 platform tag; this checker knows those two")


def objdump_for(arch, override=None):
    """`override`, or the host's objdump for the host's arch, else a cross objdump
    (``aarch64-linux-gnu-objdump``) when installed (binutils-aarch64-linux-gnu)."""
    if override:
        return override
    host = platform.machine().lower().replace("amd64", "x86_64").replace("arm64", "aarch64")
    if arch != host:
        cross = shutil.which(f"{arch}-linux-gnu-objdump")
        if cross is None:
            raise SystemExit(f"{arch} code on a {host} machine: install {arch}-linux-gnu-objdump "
                             f"(binutils-{arch.replace('_', '-')}-linux-gnu) or give --objdump")
        return cross
    return "objdump"


def check_files(sos, arch, label, objdump=None):
    bad = False
    for so in sos:
        found, notes, n = check_so(so, arch, objdump_for(arch, objdump))
        status = "ok" if not found and not notes else "FAIL"
        print(f"  {status:4} {Path(so).name}: {n} instructions, {Path(so).stat().st_size / 1e3:.0f} kB")
        items = sorted(found.items(), key=lambda kv: -len(kv[1]))
        for (why, mnem), funcs in items[:8]:
            fs = collections.Counter(funcs).most_common(2)
            print(f"       {mnem} x{len(funcs)} ({why}), in {', '.join(f for f, _ in fs)}")
        if len(items) > 8:
            print(f"       ... and {len(items) - 8} more mnemonics ({sum(len(f) for _, f in items[8:])} instructions)")
        for note in notes:
            print(f"       {note}")
        bad |= bool(found or notes)
    if not sos:
        print(f"  FAIL {label}: no .so files")
        bad = True
    return bad


def check_wheel(wheel, objdump=None):
    wheel = Path(wheel)
    arch = arch_of_wheel(wheel.name)
    size = wheel.stat().st_size
    print(f"{wheel.name}: {size / 1e6:.2f} MB ({arch} baseline)")
    bad = size > MAX_WHEEL_BYTES
    if bad:
        print(f"  FAIL size over {MAX_WHEEL_BYTES / 1e6:.0f} MB")
    with zipfile.ZipFile(wheel) as z, tempfile.TemporaryDirectory() as tmp:
        names = z.namelist()
        sources = [n for n in names if n.endswith((".c", ".cpp", ".pyx", ".html"))]
        if sources:
            print(f"  FAIL ships sources or build outputs: {', '.join(sources)}")
            bad = True
        sos = [z.extract(n, tmp) for n in names if n.endswith(".so")]
        bad |= check_files(sos, arch, wheel.name, objdump)
    return bad


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    ap.add_argument("wheels", nargs="*", help="wheel files (.whl) to check")
    ap.add_argument("--build", action="store_true",
                    help="build a wheel of this source tree first (python -m build --wheel) and check it")
    ap.add_argument("--installed", action="store_true",
                    help="check the .so files of the fusion package that Python imports, for this machine's arch")
    ap.add_argument("--so", nargs=2, metavar=("ARCH", "FILE"), action="append", default=[],
                    help="check one shared object for ARCH (x86_64 or aarch64); repeatable")
    ap.add_argument("--objdump", help="the objdump to use (default: objdump, or a cross objdump "
                    "such as aarch64-linux-gnu-objdump for another arch)")
    args = ap.parse_args(argv)
    if shutil.which(args.objdump or "objdump") is None:
        ap.error(f"{args.objdump or 'objdump'} not found (binutils)")
    if not (args.wheels or args.build or args.installed or args.so):
        ap.error("give wheels, --build, --installed or --so")
    bad = False
    for w in args.wheels:
        bad |= check_wheel(w, args.objdump)
    for arch, so in args.so:
        print(f"{so} ({arch} baseline)")
        bad |= check_files([so], arch, so, args.objdump)
    if args.build:
        root = Path(__file__).resolve().parents[1]
        with tempfile.TemporaryDirectory() as out:
            subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", out, str(root)], check=True)
            for w in sorted(Path(out).glob("*.whl")):
                bad |= check_wheel(w, args.objdump)
    if args.installed:
        spec = importlib.util.find_spec("fusion")
        if spec is None or not spec.submodule_search_locations:
            ap.error("no importable fusion package")
        pkg = Path(list(spec.submodule_search_locations)[0])
        arch = platform.machine().lower().replace("amd64", "x86_64").replace("arm64", "aarch64")
        print(f"{pkg} ({arch} baseline)")
        bad |= check_files(sorted(pkg.glob("*.so")), arch, str(pkg), args.objdump)
    print("FAIL" if bad else "OK: no instruction beyond the baseline ISA")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
