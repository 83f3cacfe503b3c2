# The two commands of the README: `make demo` and `make test`. Both set up .venv first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
SOURCES := pyproject.toml setup.py $(wildcard fusion/*.pyx fusion/*.pxd fusion/*.h envs/*.pyx)

# the kernels of the local build are compiled for this machine's CPU (setup.py: FUSION_MARCH);
# `FUSION_MARCH= make install` builds the portable copy a wheel gets
FUSION_MARCH ?= native
# the CPU build of torch, installed before the extras so that `rl`'s torch>=2.3 is met by it.
# This machine's wheelhouse (PIP_FIND_LINKS) has that build; from PyPI alone pip would take the
# multi-GB CUDA one: there, `make TORCH_INDEX=https://download.pytorch.org/whl/cpu`
TORCH ?= torch==2.13.0
TORCH_INDEX ?=

.PHONY: demo test install bench docs wheel clean

install: $(STAMP)

# Editable install: the Cython kernels are compiled by setup.py in the package build.
$(STAMP): $(SOURCES)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX)) '$(TORCH)'
	FUSION_MARCH=$(FUSION_MARCH) $(PY) -m pip install --quiet -e '.[all]'
	touch $(STAMP)

# the main job: control under every estimator with the shipped policies (quick mode)
demo: $(STAMP)
	$(PY) scripts/compare_control.py --quick

test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) benchmarks/throughput.py

# the API reference and the pages of docs/ -> site/ (mkdocs.yml)
docs: $(STAMP)
	$(PY) -m mkdocs build --strict

# the portable wheel and sdist -> dist/, the wheel checked for instructions beyond its tag
wheel: $(STAMP)
	$(PY) -m build
	$(PY) benchmarks/check_wheel_isa.py dist/*.whl

clean:
	rm -rf build dist site *.egg-info fusion/*.c fusion/*.so fusion/*.html envs/*.c envs/*.so envs/*.html
