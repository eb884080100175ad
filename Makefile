# ngcontact: every target bootstraps .venv on a fresh machine.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-slow venv clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

## demo: test 1 of [CAMWA21], FEM P1 and P2 on T0..T3 -> results/demo/
demo: $(STAMP)
	$(PY) -m ngcontact demo --out results/demo

## test: fast test suite (a few minutes on 2 cores)
test: $(STAMP)
	$(PY) -m pytest -q tests ngcontact

## test-slow: also the long convergence studies
test-slow: $(STAMP)
	$(PY) -m pytest -q -m "" tests ngcontact

clean:
	rm -rf results/runs .pytest_cache
