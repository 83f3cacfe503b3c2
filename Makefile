# The two commands of the README: `make demo` and `make test`. Both set up .venv first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
SOURCES := pyproject.toml setup.py $(wildcard fusion/*.pyx fusion/*.pxd)

.PHONY: demo test install bench clean

install: $(STAMP)

# Editable install: the Cython kernels are compiled by setup.py in the package build.
$(STAMP): $(SOURCES)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[all]'
	touch $(STAMP)

# the main job: control under every estimator with the shipped policies (quick mode)
demo: $(STAMP)
	$(PY) scripts/compare_control.py --quick

test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) benchmarks/throughput.py

clean:
	rm -rf build *.egg-info fusion/*.c fusion/*.so fusion/*.html
