"""The parameter tables of the docs and the README, generated from the one declaration of each
parameter (each estimator class's PARAMS, name -> fusion.Param), so that no page repeats a
default, unit or range by hand.

    python docs/api_tables.py            # rewrite the marked blocks in place
    python docs/api_tables.py --check    # list the files whose blocks differ (exit 1)

A block is `<!-- params NAME -->` ... `<!-- /params -->` (NAME's table), `<!-- params NAME
-BASE -->` (only the Params NAME declares differently from BASE, or BASE lacks), or
`<!-- params summary -->` (the README's one row per estimator). tests/test_docs_tables.py
checks that the committed files match. Also the mkdocs hook that fills docs/api.md's
<!-- estimator-params --> with every table."""
import math
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FILES = ("README.md", "docs/estimators.md", "docs/aekf.md", "docs/cfekf.md", "docs/madgwick.md", "docs/ukf.md")
BLOCK = re.compile(r"(<!-- params (?P<spec>[^>]*?) -->\n)(?P<body>.*?)(<!-- /params -->)", re.S)


def _classes():
    import fusion
    return {name: fusion._REGISTRY[name] for name in fusion.available()}


def _value(v):
    if isinstance(v, float):
        return f"{v:.6g}"
    return f'"{v}"' if isinstance(v, str) else repr(v)


def _cell(text):
    return text.replace("|", "\\|")


def param_table(params):
    """A Markdown table of fusion.Param declarations: name, unit, default, accepted, meaning."""
    rows = ["| name | unit | default | accepted | meaning |", "|---|---|---|---|---|"]
    rows += [f"| `{p.name}` | {p.unit} | `{_value(p.default)}` | {_cell(p.accepted)} | {_cell(p.doc)} |"
             for p in params]
    return "\n".join(rows) + "\n"


def _differing(cls, base):
    return [p for k, p in cls.PARAMS.items() if base.PARAMS.get(k) != p]


def _first_sentence(text):
    """text up to its first ". " outside parentheses (a citation's "J. Nanjing Univ." is not an end)."""
    depth = 0
    for i, c in enumerate(text):
        depth += (c == "(") - (c == ")")
        if c == "." and depth == 0 and text[i + 1:i + 2] in (" ", ""):
            return text[:i]
    return text


def _base_of(name, classes):
    """The earlier estimator whose declarations this one shares most (at least half of its
    own), or None."""
    mine = classes[name].PARAMS
    best, shared = None, 0
    for other in list(classes)[:list(classes).index(name)]:
        n = sum(1 for k, p in mine.items() if classes[other].PARAMS.get(k) == p)
        if n > shared:
            best, shared = other, n
    return best if mine and 2 * shared >= len(mine) else None


def summary_table():
    """The README's table: what each estimator is (its docstring's first sentence) and its
    parameters with defaults (as another's, with the differences, where it shares most)."""
    classes = _classes()
    rows = ["| name | what | parameters (defaults) |", "|---|---|---|"]
    for name, cls in classes.items():
        what = _first_sentence(" ".join((cls.__doc__ or "").split()))
        base = _base_of(name, classes)
        params = _differing(cls, classes[base]) if base else list(cls.PARAMS.values())
        listed = ", ".join(f"`{p.name}={_value(p.default)}`" + (f" {p.unit}" if p.unit not in ("", "1") else "")
                           + (f" ({p.accepted})" if base and getattr(classes[base].PARAMS.get(p.name), "default",
                                                                     None) == p.default else "")
                           for p in params)
        if base:
            dropped = [k for k in classes[base].PARAMS if k not in cls.PARAMS]
            listed = (f"`{base}`'s" + (f" but {', '.join(f'`{k}`' for k in dropped)}" if dropped else "")
                      + (f"; {listed}" if listed else ""))
        rows.append(f"| `{name}` | {_cell(what)} | {_cell(listed) or 'none'} |")
    return "\n".join(rows) + "\n"


def render(spec):
    """The body of the block `<!-- params spec -->`."""
    words = spec.split()
    if words == ["summary"]:
        return summary_table()
    classes = _classes()
    cls = classes[words[0]]
    if len(words) == 2 and words[1].startswith("-"):
        return param_table(_differing(cls, classes[words[1][1:]]))
    if len(words) != 1:
        raise ValueError(f"bad params block spec {spec!r}")
    return param_table(cls.PARAMS.values())


def rendered(text):
    return BLOCK.sub(lambda m: m.group(1) + render(m.group("spec")) + m.group(4), text)


def stale_files(root=ROOT):
    """The FILES whose generated blocks differ from what the code declares."""
    return [f for f in FILES if rendered((root / f).read_text()) != (root / f).read_text()]


def estimator_tables():
    """docs/api.md: every estimator's table."""
    out = ["### Parameters and defaults\n",
           "`fusion.make(name, fs, **params)` accepts these `params`; every estimator also takes "
           "`frame` and `on_invalid`. Angles are in radians, rates in rad/s (e.g. "
           f"`rest_gyro_tol` {math.radians(2):.6g} rad/s = 2 deg/s).\n"]
    for name, cls in _classes().items():
        doc = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
        out.append(f"#### `{name}` ({cls.__name__})\n\n{doc}\n")
        out.append(param_table(cls.PARAMS.values()) if cls.PARAMS else "No parameters.\n")
    return "\n".join(out)


def on_page_markdown(markdown, page, config, files):
    if "<!-- estimator-params -->" in markdown:
        markdown = markdown.replace("<!-- estimator-params -->", estimator_tables())
    return markdown


def main(argv):
    if argv[1:] == ["--check"]:
        stale = stale_files()
        print("\n".join(stale) or "the parameter tables match the code")
        return 1 if stale else 0
    for f in FILES:
        path = ROOT / f
        path.write_text(rendered(path.read_text()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
