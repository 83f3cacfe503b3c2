"""The parameter tables of the README and docs/ are generated from the estimators' fusion.Param
declarations (docs/api_tables.py): the committed pages must match the code."""
import importlib.util
from pathlib import Path

import fusion

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("api_tables", ROOT / "docs" / "api_tables.py")
api_tables = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(api_tables)


def test_committed_tables_match_the_declarations():
    assert api_tables.stale_files() == [], "run: python docs/api_tables.py"


def test_every_estimator_has_a_table_somewhere():
    text = "".join((ROOT / f).read_text() for f in api_tables.FILES)
    for name in fusion.available():
        if fusion._REGISTRY[name].PARAMS:
            assert f"<!-- params {name}" in text or f"`{name}`" in api_tables.summary_table()


def test_a_changed_default_makes_the_pages_stale(monkeypatch):
    """The check can fail: a default changed in the code and not in the pages is caught."""
    classes = api_tables._classes()
    real = classes["madgwick"]
    fake = type("Madgwick", (), {"__doc__": real.__doc__,
                                 "PARAMS": dict(real.PARAMS, beta=real.PARAMS["beta"].but(default=0.1))})
    monkeypatch.setattr(api_tables, "_classes", lambda: dict(classes, madgwick=fake))
    assert {"docs/madgwick.md", "README.md"} <= set(api_tables.stale_files())


def test_the_table_shows_unit_default_range_and_meaning():
    params = fusion._REGISTRY["ekf"].PARAMS
    table = api_tables.param_table(params.values())
    row = next(r for r in table.splitlines() if r.startswith("| `gyro_noise`"))
    assert "rad/s/√Hz" in row and f"`{params['gyro_noise'].default}`" in row
    assert "[1e-05, 10]" in row and "white-noise" in row
