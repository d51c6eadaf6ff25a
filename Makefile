# xray_viz developer entry points. `make demo` and `make test` are the README's Quick start.
SHELL := /bin/bash
.SHELLFLAGS := -o pipefail -c
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

DOCS_OUT ?= build/docs

.PHONY: setup demo test test-all docs bench clean

# Two installs into the one .venv: `make demo` the core package only (what a render needs: no
# test, docs or ct extras; of the Debian packages only the GL libraries pymeshlab links against),
# `make test` everything the tests need. Either may come first. pip shows its progress; only its
# "WARNING: Location ... ignored" notices on stderr are filtered out (pipefail keeps its status).
PIP := $(PY) -m pip
QUIET_LOCATION := 2> >(grep -v '^WARNING: Location' >&2)
CORE_STAMP := $(VENV)/.installed-core

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip $(QUIET_LOCATION)

$(CORE_STAMP): pyproject.toml .ci/system-deps | $(VENV)/bin/python
	bash .ci/system-deps core
	if [ -f $(STAMP) ] && [ $(STAMP) -nt pyproject.toml ]; then :; else \
	  $(PIP) install -e . $(QUIET_LOCATION); fi
	touch $(CORE_STAMP)

$(STAMP): pyproject.toml .ci/system-deps | $(VENV)/bin/python
	bash .ci/system-deps
	$(PIP) install -e '.[test,docs,ct]' $(QUIET_LOCATION)
	touch $(STAMP)

setup: $(STAMP)

## Render the bundled default scene to out/default.png (and print where it went): the core only.
demo: $(CORE_STAMP)
	$(VENV)/bin/xray-viz render default -o out/default.png

## Run the test suite (a bounded sample of the slow stress cases included).
test: setup
	$(PY) -m pytest -q

## Everything, including every slow stress case (and mbirjax, ~1 GB, for its slow reconstructions).
test-all: setup
	$(PIP) install -e '.[test,docs,ct,ct-mbir]' $(QUIET_LOCATION)
	$(PY) -m pytest -q -m "slow or not slow"

## The documentation site: build/docs/html/index.html (every walkthrough executed; warnings are
## errors). Re-runs only the walkthroughs that changed (sphinx-gallery keeps docs/walkthroughs/).
docs: setup
	$(PY) -m sphinx -b html -W --keep-going -q -d $(DOCS_OUT)/doctrees docs $(DOCS_OUT)/html
	@echo "open $(DOCS_OUT)/html/index.html (interactive 3D views: python -m http.server -b 127.0.0.1 -d $(DOCS_OUT)/html)"

## Benchmarks against the peers (installs the bench extra and the peers' Debian packages).
bench: setup
	bash benchmarks/run.sh

clean:
	rm -rf $(VENV) out build *.egg-info docs/walkthroughs docs/examples docs/api/generated \
	  docs/api/backreferences docs/_readme
