# Two entry points: `make demo` and `make test`. Both create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-all lint bench clean

# two workers (the 2-core CI machine); slow cases only in CI (CI=1, set by .ci/run) or test-all
JOBS ?= 2
SLOW := $(if $(CI),,-m "not slow")

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

# plotly.js with only the trace types the report pages draw (1.8 MB instead of 4.8 MB: pages
# open about 0.7 s sooner), built from the npm registry with the pinned tools/plotly-bundle; without
# npm, or if the build fails, the pages embed the plotly package's full plotly.min.js instead
BUNDLE := src/rigcal/report/js/plotly-rigcal.min.js
BUNDLE_TOOL := tools/plotly-bundle

$(BUNDLE): $(BUNDLE_TOOL)/package-lock.json $(BUNDLE_TOOL)/entry.js $(BUNDLE_TOOL)/build.js
	@if command -v npm >/dev/null 2>&1; then \
	  (cd $(BUNDLE_TOOL) && npm ci --no-audit --no-fund --loglevel=error >/dev/null && npm run --silent build >/dev/null 2>&1) \
	  && echo "built $@" \
	  || echo "note: building $@ failed: report.html embeds the full plotly.min.js (opens about 0.7 s later)"; \
	else echo "note: npm not found: report.html embeds the full plotly.min.js (opens about 0.7 s later)"; fi

demo: $(STAMP) $(BUNDLE)
	$(BIN)/rigcal demo --out demo_out

test: $(STAMP) $(BUNDLE)
	$(BIN)/python -m pytest -p no:cacheprovider -n $(JOBS) $(SLOW)

test-all: $(STAMP) $(BUNDLE)
	$(BIN)/python -m pytest -p no:cacheprovider -n $(JOBS)

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_solvers.py

clean:
	rm -rf $(VENV) demo_out .pytest_cache $(BUNDLE) $(BUNDLE_TOOL)/node_modules
