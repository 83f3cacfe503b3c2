"""Packaging: the ISA checker's rules, one version source, plotting that leaves the user's
matplotlib backend alone, and the sdist's manifest."""
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

try:
    import tomllib
except ImportError:  # Python 3.10
    tomllib = None

ROOT = Path(__file__).resolve().parents[1]


def _checker():
    spec = importlib.util.spec_from_file_location("_check_wheel_isa", ROOT / "benchmarks" / "check_wheel_isa.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("mnemonic, operands, bad", [
    ("addsd", "%xmm1,%xmm0", False),             # SSE2: baseline
    ("mulpd", "0x10(%rsp),%xmm3", False),
    ("sqrtsd", "%xmm0,%xmm0", False),
    ("pextrw", "$0x1,%xmm0,%eax", False),         # SSE2's pextrw, unlike SSE4.1's pextrd
    ("vfmadd231sd", "%xmm2,%xmm1,%xmm0", True),   # FMA
    ("vaddpd", "%ymm1,%ymm2,%ymm3", True),        # AVX
    ("vmovapd", "%zmm0,(%rax)", True),            # AVX-512
    ("movapd", "%xmm17,%xmm0", True),             # EVEX-only register
    ("pextrd", "$0x1,%xmm0,%eax", True),          # SSE4.1
    ("roundsd", "$0x9,%xmm0,%xmm0", True),
    ("pshufb", "%xmm1,%xmm0", True),              # SSSE3
    ("popcnt", "%rax,%rax", True),
    ("lock", "cmpxchg %rdx,(%rcx)", False),
    ("rep", "stos %rax,%es:(%rdi)", False),
])
def test_isa_rules_x86_64(mnemonic, operands, bad):
    assert (_checker().offending("x86_64", mnemonic, operands, "f") is not None) == bad


@pytest.mark.parametrize("mnemonic, operands, func, bad", [
    ("fmadd", "d0, d1, d2, d3", "f", False),      # scalar FMA is ARMv8.0-A
    ("fmla", "v0.2d, v1.2d, v2.2d", "f", False),  # NEON
    ("ldaxr", "w1, [x0]", "f", False),
    ("ldaddal", "w1, w2, [x0]", "f", True),       # LSE atomics (ARMv8.1)
    ("ldaddal", "w1, w2, [x0]", "__aarch64_ldadd4_acq_rel", False),  # libgcc: chosen at run time
    ("sdot", "v0.4s, v1.16b, v2.16b", "f", True),
    ("fadd", "z0.d, z1.d, z2.d", "f", True),      # SVE
    ("crc32x", "w0, w0, x1", "f", True),
])
def test_isa_rules_aarch64(mnemonic, operands, func, bad):
    assert (_checker().offending("aarch64", mnemonic, operands, func) is not None) == bad


def test_isa_rules_unknown_arch():
    with pytest.raises(ValueError, match="arch"):
        _checker().offending("riscv64", "add", "a0, a0, a1", "f")


def test_one_version_source():
    if tomllib is None:
        pytest.skip("tomllib: Python 3.11+")
    import fusion
    py = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in py["project"] and "version" in py["project"]["dynamic"]
    assert py["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "fusion._version.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", fusion.__version__)
    assert f"version: {fusion.__version__}" in (ROOT / "CITATION.cff").read_text()


def test_plotting_keeps_the_users_backend(tmp_path):
    pytest.importorskip("matplotlib")
    code = ("import sys, matplotlib, numpy as np; matplotlib.use('svg'); "
            "from benchmarks import compare; "
            f"p = compare.plot_errors({{'a': {{'x': np.ones(50)}}}}, {str(tmp_path / 'e.png')!r}, 't', fs=10.0); "
            "assert p.stat().st_size > 1000; "
            "assert matplotlib.get_backend() == 'svg', matplotlib.get_backend(); "
            "assert 'matplotlib.pyplot' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=str(ROOT))


def test_library_never_switches_the_backend():
    calls = [f"{p.relative_to(ROOT)}:{i}" for d in ("fusion", "envs", "controllers") for p in (ROOT / d).rglob("*.py")
             for i, line in enumerate(p.read_text().splitlines(), 1) if "matplotlib.use(" in line]
    assert not calls, calls


def test_extras_cover_the_imports():
    """What each extra promises: PID evaluation with [sim] needs scipy (evaluate's
    confidence intervals) and the simulator; torch is not pinned."""
    if tomllib is None:
        pytest.skip("tomllib: Python 3.11+")
    opt = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]

    def names(extra):
        return {re.split(r"[<>=!\[ ]", r, maxsplit=1)[0] for r in opt[extra]}

    assert {"gymnasium", "pybullet", "scipy", "spherebot-fusion"} <= names("sim")
    assert "spherebot-fusion[plot]" in opt["sim"]
    assert {"matplotlib", "tqdm"} <= names("plot")
    torch = [r for r in opt["rl"] if r.startswith("torch")]
    assert torch == ["torch>=2.3"]
    base = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert [re.split(r"[<>=]", r)[0] for r in base] == ["numpy"]


_KERNEL_C = """
void axpy(int n, double a, const double *x, double *y) {
    for (int i = 0; i < n; i++) y[i] = a * x[i] + y[i];
}
"""


@pytest.mark.parametrize("flags, bad", [
    (["-O3"], False),                          # the baseline: SSE2
    (["-O3", "-march=haswell"], True),         # AVX2 + FMA: ymm registers, vfmadd
    (["-O3", "-g"], True),                     # debug sections and symbols: not a wheel's
])
def test_isa_checker_on_compiled_code(tmp_path, flags, bad):
    """The checker end to end on a shared object the C compiler builds (x86-64 hosts)."""
    import platform
    import shutil
    if platform.machine() != "x86_64" or not shutil.which("gcc") or not shutil.which("objdump"):
        pytest.skip("needs gcc and objdump on x86-64")
    (tmp_path / "k.c").write_text(_KERNEL_C)
    so = tmp_path / "k.so"
    strip = [] if "-g" in flags else ["-s"]
    subprocess.run(["gcc", "-shared", "-fPIC", *flags, *strip, str(tmp_path / "k.c"), "-o", str(so)], check=True)
    assert _checker().main(["--so", "x86_64", str(so)]) == (1 if bad else 0)


HEAVY = ("matplotlib", "tqdm", "scipy", "torch", "pybullet", "gymnasium")


@pytest.mark.parametrize("module, allowed", [
    ("fusion", ()),                                        # numpy and the kernels only
    ("fusion.metrics, fusion.quat, fusion.datasets, fusion.scenarios, fusion.imu", ()),
    ("envs", ("gymnasium",)),                              # registration; no torch, no physics client
])
def test_imports_stay_light(module, allowed):
    """What a package pulls in at import (DESIGN: `import fusion` needs numpy and the kernels;
    the simulator needs no torch), in a fresh interpreter."""
    code = (f"import sys, {module}; "
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(ROOT), timeout=120)
    assert out.returncode == 0, out.stderr
    pulled = set(out.stdout.split()) - set(allowed)
    assert not pulled, f"import {module} pulled in {sorted(pulled)}"


def test_the_import_check_sees_a_heavy_module():
    code = f"import sys, fractions, json; print(' '.join(m for m in {HEAVY + ('json',)!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["json"]


def test_console_scripts_resolve_into_the_wheels_packages():
    """Every console script names a `main` in a package the wheel ships (the experiments'
    commands in `benchmarks`, none in the library `fusion`)."""
    if tomllib is None:
        pytest.skip("tomllib: Python 3.11+")
    import importlib
    py = tomllib.loads((ROOT / "pyproject.toml").read_text())
    packages = py["tool"]["setuptools"]["packages"]
    scripts = py["project"]["scripts"]
    for name, target in scripts.items():
        module, func = target.split(":")
        assert module.split(".")[0] in packages, (name, target)
        assert callable(getattr(importlib.import_module(module), func)), (name, target)
    assert not [t for t in scripts.values() if t.startswith("fusion.")], "commands belong to the experiments"
    assert not [p.name for p in (ROOT / "fusion").glob("*.py") if p.stem in ("compare", "papers", "papers_cli",
                                                                              "estimators_cli")]


def test_the_extras_checked_are_pyprojects():
    """fusion.checks.EXTRAS (what the commands check) names pyproject.toml's extras, the one
    each includes and their distributions by import name."""
    if tomllib is None:
        pytest.skip("tomllib: Python 3.11+")
    from fusion.checks import EXTRAS
    opt = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    import_name = {"pyyaml": "yaml"}                   # the one distribution not imported by its own name
    for extra, (include, modules) in EXTRAS.items():
        dists = [re.split(r"[<>=!\[ ]", r, maxsplit=1)[0].lower() for r in opt[extra]]
        own = {import_name.get(d, d.replace("-", "_")) for d in dists if d != "spherebot-fusion"}
        assert set(modules) == own, extra
        assert [r for r in opt[extra] if r.startswith("spherebot-fusion")] == (
            [f"spherebot-fusion[{include}]"] if include else []), extra


def _without(blocked, code):
    """Run code in a fresh interpreter where the modules ``blocked`` cannot be imported (a None
    in sys.modules: `import` raises ImportError, find_spec gives None), as if not installed."""
    code = f"import sys; sys.modules.update(dict.fromkeys({list(blocked)!r})); " + code
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(ROOT), timeout=120)


@pytest.mark.parametrize("module, argv, blocked, command, extra", [
    ("controllers.compare", ["--quick", "--out", "{out}"], ["gymnasium"], "spherebot-compare", "sim"),
    # sim includes plot
    ("controllers.compare", ["--quick", "--out", "{out}"], ["matplotlib"], "spherebot-compare", "sim"),
    ("controllers.compare", ["--quick", "--out", "{out}"], ["torch"], "spherebot-compare with a ppo controller", "rl"),
    ("controllers.compare", ["--quick", "--out", "{out}", "--controllers", "pid", "--backend", "ray"], ["ray"],
     "spherebot-compare --backend ray", "ray"),
    ("controllers.train_cli", ["--algo", "ppo", "--env", "track", "-f", "{out}"], ["torch"], "spherebot-train", "rl"),
    ("benchmarks.estimators_cli", ["--quick", "--out", "{out}"], ["matplotlib"], "spherebot-estimators", "plot"),
    ("benchmarks.papers_cli", ["--quick", "--out", "{out}"], ["tqdm"], "spherebot-papers", "plot"),
])
def test_a_command_without_its_extra_says_which_to_install(tmp_path, module, argv, blocked, command, extra):
    """Before any work (nothing written): exit 2 and the extra to install, not a traceback."""
    out = tmp_path / "out"
    argv = [a.format(out=out) for a in argv]
    r = _without(blocked, f"from {module} import main; sys.exit(main({argv!r}))")
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == (f"error: {command} needs the {extra!r} extra ({blocked[0]} not installed): "
                                f"pip install 'spherebot-fusion[{extra}]'")
    assert not out.exists()


def test_compare_needs_rl_only_for_a_ppo_controller():
    r = _without(["torch", "stable_baselines3"],
                 "from controllers.compare import main; sys.exit(main(['--controllers', 'pid', '--workers', '0']))")
    assert r.returncode == 2 and r.stderr.strip() == "error: --workers must be >= 1, got 0", r.stderr


def test_envs_without_gymnasium_names_the_extra():
    r = _without(["gymnasium"], "import envs")
    assert r.returncode == 1
    assert ("ModuleNotFoundError: envs needs the 'sim' extra (gymnasium not installed): "
            "pip install 'spherebot-fusion[sim]'") in r.stderr


@pytest.mark.parametrize("call", ["load_policy('ppo-waypoints-ekf')", "train('ppo', 'waypoints', 'ekf', timesteps=8)",
                                  "make_vec_env('track', 'ekf', 1, 0)", "clone_teacher(None, None, None, 8)"])
def test_the_rl_functions_without_torch_name_the_extra(call):
    """`import controllers.rl` stays light; its functions that need torch say which extra to install."""
    r = _without(["torch"], f"import controllers.rl as rl; rl.{call}")
    assert r.returncode == 1
    assert (f"ModuleNotFoundError: controllers.rl.{call.split('(')[0]} needs the 'rl' extra (torch not installed): "
            "pip install 'spherebot-fusion[rl]'") in r.stderr, r.stderr


def test_the_bank_benchmark_skips_vqf_when_absent():
    """vqf is a peer of the benchmark, not a dependency: without it the bank section still runs."""
    r = _without(["vqf"], "from benchmarks import throughput as t; from benchmarks.peers import Data; "
                          "text, _ = t.bank_section(Data.mixed(800, fs=t.FS), 800, 1); print(text)")
    assert r.returncode == 0, r.stderr
    assert "skipping vqf" in r.stdout and "VQF" not in r.stdout.split("rounds:")[-1]
