# vista: `make run` serves the supervisor, `make test` runs the whole suite.
# Both install what they need on first use and re-use it afterwards.

VENV        ?= .venv
PYTHON      ?= python3
PY          := $(VENV)/bin/python
VISTA       := $(VENV)/bin/vista
DEB_PACKAGES := python3-venv python3-dev build-essential
STAMP_RUN   := $(VENV)/.installed-run
STAMP_TEST  := $(VENV)/.installed-test
# Test files are shared among this many pytest-xdist workers, each file whole on one worker
# (the broker's tests all live in tests/test_engine.py, so one worker owns the Redis queues).
TEST_WORKERS ?= 2
WEB         := clients/web
WEB_STAMP   := $(WEB)/node_modules/.installed
WEB_BUILT   := $(WEB)/dist/index.html
# The browser, C# and HTTP pieces the client tests use: Debian's Chromium (no browser
# download), mono's C# compiler, runtime and System.Net.Http (Node.js and npm: see below).
TEST_DEB_PACKAGES := chromium mono-mcs mono-runtime libmono-system-net-http4.0-cil

.PHONY: run test install install-test lint bench clean web

run: $(STAMP_RUN) $(WEB_BUILT)
	$(VISTA) migrate
	$(VISTA) serve

test: $(STAMP_TEST)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

lint: $(STAMP_TEST)
	$(VENV)/bin/ruff check contract supervisor services benches tests clients/python
	$(VENV)/bin/ruff format --check contract supervisor services benches tests clients/python

install: $(STAMP_RUN) $(WEB_BUILT)
install-test: $(STAMP_TEST)
web: $(WEB_BUILT)

$(VENV)/bin/activate:
	@$(PYTHON) -m venv --help >/dev/null 2>&1 && $(PYTHON) -c "import ensurepip" 2>/dev/null || \
	  { echo "installing Debian packages: $(DEB_PACKAGES)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(DEB_PACKAGES); }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip setuptools wheel

# torch is pinned to 2.13.0 in pyproject.toml: that takes the local CPU build.
# open3d needs Debian's libusb-1.0-0. `vista precompile` fills numba's cache (about a
# minute), so that no user's first measurement waits for the compiler.
$(STAMP_RUN): pyproject.toml clients/python/pyproject.toml | $(VENV)/bin/activate
	@ldconfig -p | grep -q 'libusb-1.0.so.0' || \
	  { echo "installing Debian package libusb-1.0-0 (for open3d)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0; }
	$(PY) -m pip install -q -e ".[cad]" -e clients/python
	$(VISTA) precompile
	@touch $@

$(STAMP_TEST): pyproject.toml $(STAMP_RUN) $(WEB_BUILT)
	@missing=$$(for p in $(TEST_DEB_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	  [ -z "$$missing" ] || { echo "installing Debian packages:" $$missing; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; }
	$(PY) -m pip install -q -e ".[test]"
	@touch $@

# The dashboard: npm packages from the registry only (package-lock.json), bundled by esbuild.
$(WEB_STAMP): $(WEB)/package.json $(WEB)/package-lock.json
	@command -v npm >/dev/null || { echo "installing Debian packages nodejs npm"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nodejs npm; }
	cd $(WEB) && npm ci --no-audit --no-fund --loglevel=error
	@touch $@

$(WEB_BUILT): $(WEB_STAMP) $(wildcard $(WEB)/src/*) $(WEB)/tools/build.mjs
	cd $(WEB) && npm run --silent build

clean:
	rm -rf $(VENV) vista-data bench-results .pytest_cache $(WEB)/node_modules $(WEB)/dist
