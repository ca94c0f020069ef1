# Two commands for a fresh Debian 12 machine: `make demo` and `make test`.
# Both set up what they need first (Debian package, .venv, pinned requirements, this package);
# with nothing changed, the set-up step is a no-op that takes about a second.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup test demo colcon-check clean

setup: $(STAMP)

# Node files are listed so that a new node gets its console script on the next run.
$(STAMP): requirements.txt requirements-dev.txt setup.py setup.cfg package.xml $(wildcard absscale_ros/nodes/*.py)
	@# Open3D loads libusb-1.0 at import time; Debian ships it as libusb-1.0-0.
	@if ! ldconfig -p | grep -q 'libusb-1.0.so.0'; then \
		echo 'installing Debian package libusb-1.0-0'; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0; fi
	@[ -x $(BIN)/python ] || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade 'pip==26.3' 'setuptools==79.0.1' 'wheel==0.48.0'
	$(BIN)/python -m pip install -q -r requirements.txt -r requirements-dev.txt
	$(BIN)/python -m pip install -q --no-deps --no-build-isolation -e .
	@touch $(STAMP)

test: setup
	$(BIN)/python -m pytest -q test

demo: setup
	$(BIN)/absscale demo

# Proves the package still builds as an ament_python package with colcon (CI runs it as a test).
colcon-check: setup
	$(BIN)/python -m pytest -q test/test_colcon_build.py

clean:
	rm -rf $(VENV) build install log *.egg-info
