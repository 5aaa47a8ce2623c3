# Two entry points: `make demo` and `make test`. Both create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-all lint bench clean plotly-bundle

# two workers (the 2-core CI machine); slow cases only in CI (CI=1, set by .ci/run) or test-all
JOBS ?= 2
SLOW := $(if $(CI),,-m "not slow")

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

# plotly.js with only the trace types the report pages draw (1.8 MB instead of 4.8 MB), committed
# with its licenses; `make plotly-bundle` rebuilds it from the npm registry with the pinned
# tools/plotly-bundle (a slow test checks that the rebuild is byte-identical)
BUNDLE_TOOL := tools/plotly-bundle

demo: $(STAMP)
	$(BIN)/rigcal demo --out demo_out

test: $(STAMP)
	$(BIN)/python -m pytest -p no:cacheprovider -n $(JOBS) $(SLOW) --durations=40

test-all: $(STAMP)
	$(BIN)/python -m pytest -p no:cacheprovider -n $(JOBS)

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_solvers.py

clean:
	rm -rf $(VENV) demo_out .pytest_cache $(BUNDLE_TOOL)/node_modules

plotly-bundle:
	cd $(BUNDLE_TOOL) && npm ci --no-audit --no-fund --loglevel=error && npm run --silent build
