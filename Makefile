# vista: `make run` serves the supervisor, `make test` runs the whole suite.
# Both install what they need on first use and re-use it afterwards.

VENV        ?= .venv
PYTHON      ?= python3
PY          := $(VENV)/bin/python
VISTA       := $(VENV)/bin/vista
DEB_PACKAGES := python3-venv python3-dev build-essential
STAMP_RUN   := $(VENV)/.installed-run
STAMP_TEST  := $(VENV)/.installed-test

.PHONY: run test install install-test lint bench clean

run: $(STAMP_RUN)
	$(VISTA) migrate
	$(VISTA) serve

test: $(STAMP_TEST)
	$(PY) -m pytest -q

lint: $(STAMP_TEST)
	$(VENV)/bin/ruff check supervisor services tests
	$(VENV)/bin/ruff format --check supervisor services tests

install: $(STAMP_RUN)
install-test: $(STAMP_TEST)

$(VENV)/bin/activate:
	@$(PYTHON) -m venv --help >/dev/null 2>&1 && $(PYTHON) -c "import ensurepip" 2>/dev/null || \
	  { echo "installing Debian packages: $(DEB_PACKAGES)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(DEB_PACKAGES); }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip setuptools wheel

# torch is pinned to 2.13.0 in pyproject.toml: that takes the local CPU build.
# open3d needs Debian's libusb-1.0-0.
$(STAMP_RUN): pyproject.toml | $(VENV)/bin/activate
	@ldconfig -p | grep -q 'libusb-1.0.so.0' || \
	  { echo "installing Debian package libusb-1.0-0 (for open3d)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0; }
	$(PY) -m pip install -q -e .
	@touch $@

$(STAMP_TEST): pyproject.toml $(STAMP_RUN)
	$(PY) -m pip install -q -e ".[test]"
	@touch $@

clean:
	rm -rf $(VENV) vista-data bench-results .pytest_cache
