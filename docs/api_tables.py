"""mkdocs hook: replaces <!-- estimator-params --> in a page with one table per estimator,
read from the code (the registry of fusion.make and each class's PARAMS), so the published
defaults cannot drift from the kernels'."""
import math


def _default(v):
    return f"`{v:.6g}`" if isinstance(v, float) else f"`{v!r}`"


def estimator_tables():
    import fusion
    out = ["### Parameters and defaults\n",
           "`fusion.make(name, fs, **params)` accepts these `params`; every estimator also takes "
           "`frame` and `on_invalid`. Angles are in radians, rates in rad/s (e.g. "
           f"`rest_gyro_tol` {math.radians(2):.6g} rad/s = 2 deg/s).\n"]
    for name in fusion.available():
        cls = type(fusion.make(name, 100.0))
        doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        doc = " ".join(doc.split())
        out.append(f"#### `{name}` ({cls.__name__})\n\n{doc}\n")
        if not cls.PARAMS:
            out.append("No parameters.\n")
            continue
        out.append("| parameter | default |\n|---|---|")
        out += [f"| `{k}` | {_default(v)} |" for k, v in cls.PARAMS.items()]
        out.append("")
    return "\n".join(out)


def on_page_markdown(markdown, page, config, files):
    if "<!-- estimator-params -->" in markdown:
        markdown = markdown.replace("<!-- estimator-params -->", estimator_tables())
    return markdown
