"""Code health the linter does not check: no function over 60 lines (Python, and the Cython of
the kernels outside their per-sample steps, which are long by nature: one sample's whole maths,
kept inline for speed), and the physical constants declared once (fusion.constants)."""
import ast
import re
import subprocess
from pathlib import Path

import pytest

from fusion import constants

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 60
# functions still over the limit, each to be split (then removed from here): (path, name) -> its
# length today, which it may not exceed (a listed function that grows fails too).
KNOWN_LONG = {
}


def _python_files():
    try:
        out = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True, check=True)
        return [ROOT / f for f in out.stdout.split()]
    except (OSError, subprocess.CalledProcessError):       # not a git checkout
        return [p for p in ROOT.rglob("*.py") if "build" not in p.parts and ".venv" not in p.parts]


def _function_lengths():
    for path in _python_files():
        rel = path.relative_to(ROOT).as_posix()
        for node in ast.walk(ast.parse(path.read_text(), rel)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield rel, node.name, node.end_lineno - node.lineno + 1


def test_no_function_over_60_lines():
    long = {(rel, name): n for rel, name, n in _function_lengths() if n > MAX_LINES}
    new = {k: n for k, n in long.items() if k not in KNOWN_LONG}
    assert not new, f"functions over {MAX_LINES} lines (split them): {new}"
    grown = {k: (n, long[k]) for k, n in KNOWN_LONG.items() if long.get(k, 0) > n}
    assert not grown, f"listed long functions that grew (listed, now): {grown}"


# the kernels' per-sample steps (one sample or one physics step each), the only Cython
# functions allowed over MAX_LINES: (path, name)
PER_SAMPLE_STEPS = {
    ("fusion/_aekf.pyx", "_step"), ("fusion/_madgwick.pyx", "_step"), ("fusion/_mahony.pyx", "mahony_step"),
    ("fusion/_ukf.pyx", "correct"), ("fusion/_qmath.pxd", "quat_measurement_update"),
    ("fusion/_wahba.pxd", "quest2"), ("fusion/_magdist.pxd", "magd_check"), ("fusion/_imu.pyx", "step_c"),
    ("envs/_signals.pyx", "_sense"), ("envs/_signals.pyx", "_advance"), ("envs/_signals.pyx", "_finish"),
}
_CYTHON_DEF = re.compile(r"^(\s*)c?p?def\s+(?!class\b|struct\b|enum\b|extern\b|union\b|fused\b)[^(]*?(\w+)\s*\(")


def _cython_function_lengths(text):
    """(name, lines) of every function defined (not only declared) in a .pyx / .pxd: from its
    def line to its body's last line, the body being the lines indented deeper than the def."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        m = _CYTHON_DEF.match(line)
        if not m:
            continue
        depth, j = 0, i
        while True:         # the signature, to its closing parenthesis
            depth += lines[j].count("(") - lines[j].count(")")
            if depth <= 0 or j + 1 == len(lines):
                break
            j += 1
        if not lines[j].split("#")[0].rstrip().endswith(":"):
            continue        # a declaration (a .pxd's), no body
        indent, end = len(m.group(1)), j
        for k in range(j + 1, len(lines)):
            s = lines[k]
            if s.strip() and not s.lstrip().startswith("#"):
                if len(s) - len(s.lstrip()) <= indent:
                    break
                end = k
        yield m.group(2), end - i + 1


def test_no_cython_function_over_60_lines_but_the_per_sample_steps():
    files = [p for pkg in ("fusion", "envs") for ext in ("pyx", "pxd") for p in sorted((ROOT / pkg).glob(f"*.{ext}"))]
    long = {(p.relative_to(ROOT).as_posix(), name): n for p in files
            for name, n in _cython_function_lengths(p.read_text()) if n > MAX_LINES}
    assert set(long) - PER_SAMPLE_STEPS == set(), f"Cython functions over {MAX_LINES} lines (split them): {long}"
    assert PER_SAMPLE_STEPS - set(long) == set(), "listed steps now short: take them off PER_SAMPLE_STEPS"


def test_the_cython_checker_sees_a_long_function_and_skips_declarations():
    src = ("cdef inline double f(double x,\n                       double y) noexcept nogil:\n"
           + "    x += 1\n" * 70 + "\ncdef void g(double x) noexcept nogil\ncdef class C:\n    pass\n")
    assert list(_cython_function_lengths(src)) == [("f", 72)]


def test_the_checker_sees_a_long_function():
    src = "def f():\n" + "    x = 1\n" * 70
    (node,) = ast.parse(src).body
    assert node.end_lineno - node.lineno + 1 == 71 > MAX_LINES


def test_gravity_has_two_values_for_two_facts():
    assert constants.GRAVITY == 9.81
    assert constants.STANDARD_GRAVITY == 9.80665


# the modules' own names for them: aliases of fusion.constants, and the numpy references' copy
# (tests/reference.py imports nothing of fusion, to stay independent)
@pytest.mark.parametrize("module, attr, which", [
    ("fusion.scenarios", "G", "GRAVITY"),
    ("fusion.imu", "G0", "STANDARD_GRAVITY"),
    ("reference", "G", "GRAVITY"),
])
def test_copies_of_the_constants_agree(module, attr, which):
    import importlib
    assert getattr(importlib.import_module(module), attr) == getattr(constants, which)


def test_envs_gravity_agrees():
    pytest.importorskip("pybullet")
    from envs import base, robot
    assert base.G is constants.GRAVITY
    assert "9.81" not in Path(robot.__file__).read_text()


def _stub_names(path):
    """(module-level names, {class: member names}, {class: base names}) a .pyi declares."""
    top, members, bases = set(), {}, {}
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ClassDef):
            top.add(node.name)
            members[node.name] = {n.name for n in node.body if isinstance(n, ast.FunctionDef)} | {
                n.target.id for n in node.body if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)}
            bases[node.name] = {b.id for b in node.bases if isinstance(b, ast.Name)}
        elif isinstance(node, ast.FunctionDef):
            top.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            top.add(node.target.id)
    return top, members, bases


STUBS = sorted((ROOT / "fusion").glob("_*.pyi"))
# stub-only classes (a leading underscore): groups of attributes several kernels share, checked
# on every class that derives from one
STUB_ONLY = {c: ms for p in STUBS for c, ms in _stub_names(p)[1].items() if c.startswith("_")}


def test_every_kernel_module_has_a_stub():
    kernels = {p.stem for p in (ROOT / "fusion").glob("_*.pyx")}
    assert kernels <= {p.stem for p in STUBS}, kernels - {p.stem for p in STUBS}


@pytest.mark.parametrize("stub", STUBS, ids=[p.stem for p in STUBS])
def test_stub_names_exist_at_run_time(stub):
    import importlib
    mod = importlib.import_module(f"fusion.{stub.stem}")
    top, members, bases = _stub_names(stub)
    missing = [n for n in top if n != "Array" and n not in STUB_ONLY and not hasattr(mod, n)]
    for c, ms in members.items():
        if c not in STUB_ONLY:
            ms = ms.union(*(STUB_ONLY.get(b, set()) for b in bases[c]))
            missing += [f"{c}.{m}" for m in ms if not hasattr(getattr(mod, c), m)]
    assert not missing, f"{stub.name} declares names the module does not have: {missing}"


def test_the_data_location_is_declared_once():
    """Code points at the recorded data through fusion.datasets (ENV_VAR, DEFAULT_DATA_DIR),
    never by a path of its own."""
    pattern = re.compile(r"\.\./shared|[\"']shared[\"']\s*/")
    files = sorted(set(_python_files()) | {p for ext in ("pyx", "pxd", "pyi") for p in ROOT.glob(f"*/*.{ext}")})
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in files
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert len(hits) == 1 and hits[0].startswith("fusion/datasets.py:"), hits


def test_the_library_packages_do_not_import_the_experiments():
    """fusion, envs and controllers are libraries: none imports benchmarks, scripts or tests
    (controllers took benchmarks.compare.new_figure, which now lives in controllers.plots)."""
    lib = ("fusion/", "envs/", "controllers/")
    hits = []
    for path in _python_files():
        rel = path.relative_to(ROOT).as_posix()
        if not rel.startswith(lib):
            continue
        for node in ast.walk(ast.parse(path.read_text(), rel)):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            hits += [f"{rel}:{node.lineno} {n}" for n in names
                     if n.split(".")[0] in ("benchmarks", "scripts", "tests")]
    assert hits == []


# the public API: the library modules' public functions and the public methods of their public
# classes (the compiled kernels are typed by their .pyi stubs, checked above)
TYPED_MODULES = ["fusion", "fusion.bank", "fusion.metrics", "fusion.quat", "fusion.datasets", "fusion.scenarios",
                 "fusion.imu", "fusion.checks", "fusion.params", "controllers.base", "controllers.pid",
                 "controllers.rl", "controllers.policy_io", "controllers.curves", "controllers.plots",
                 "envs.base", "envs.track", "envs.waypoints", "envs.robot", "envs.vector", "envs.sphere"]


def _untyped(module):
    """'name(unannotated parameters) ->?' for each public function of module without full hints."""
    import importlib
    import inspect
    m = importlib.import_module(module)
    funcs = []
    for n in getattr(m, "__all__", [n for n in dir(m) if not n.startswith("_")]):
        o = getattr(m, n)
        if getattr(o, "__module__", None) != module:
            continue
        if inspect.isfunction(o):
            funcs.append((n, o))
        elif inspect.isclass(o):
            for k, v in vars(o).items():
                f = v.__func__ if isinstance(v, (classmethod, staticmethod)) else v
                if inspect.isfunction(f) and (not k.startswith("_") or k == "__init__"):
                    funcs.append((f"{n}.{k}", f))
    out = []
    for qn, f in funcs:
        sig = inspect.signature(f)
        bare = [p for p, d in sig.parameters.items() if p not in ("self", "cls") and d.annotation is d.empty]
        if bare or sig.return_annotation is sig.empty:
            out.append(f"{qn}({', '.join(bare)})" + (" ->?" if sig.return_annotation is sig.empty else ""))
    return out


@pytest.mark.parametrize("module", TYPED_MODULES)
def test_the_public_api_has_type_hints(module):
    if module.startswith("envs"):
        pytest.importorskip("pybullet")
    assert _untyped(module) == []


def test_the_hint_check_sees_a_bare_function(tmp_path, monkeypatch):
    (tmp_path / "bare_mod.py").write_text("def f(x, y: int):\n    return x\n\ndef g() -> None:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert _untyped("bare_mod") == ["f(x) ->?"]
