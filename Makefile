# xray_viz developer entry points. `make demo` and `make test` are the README's Quick start.
SHELL := /bin/bash
.SHELLFLAGS := -o pipefail -c
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

DOCS_OUT ?= build/docs

.PHONY: setup demo test test-all docs bench clean

$(STAMP): pyproject.toml .ci/system-deps
	bash .ci/system-deps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip 2>&1 | { grep -v '^WARNING: Location' || true; }
	$(PY) -m pip install --quiet -e '.[test,docs,ct]' 2>&1 | { grep -v '^WARNING: Location' || true; }
	touch $(STAMP)

setup: $(STAMP)

## Render the bundled default scene to out/default.png (and print where it went).
demo: setup
	$(VENV)/bin/xray-viz render default -o out/default.png

## Run the test suite (a bounded sample of the slow stress cases included).
test: setup
	$(PY) -m pytest -q

## Everything, including every slow stress case (and mbirjax, ~1 GB, for its slow reconstructions).
test-all: setup
	$(PY) -m pip install --quiet -e '.[test,docs,ct,ct-mbir]' 2>&1 | { grep -v '^WARNING: Location' || true; }
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
	rm -rf $(VENV) out build *.egg-info docs/walkthroughs docs/api/generated
