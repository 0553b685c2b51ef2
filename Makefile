# Two commands for a newcomer: `make demo` and `make test`. Everything installs into .venv.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Tests talk DDS on loopback only, in a domain of their own.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: install demo test test-fast bench lint clean

install: $(STAMP)

$(STAMP): setup.py setup.cfg requirements.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt
	$(PY) -m pip install -q --no-deps -e .
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/landing-zone demo

test: $(STAMP)
	$(PY) -m pytest -q test

test-fast: $(STAMP)
	$(PY) -m pytest -q -m "not slow" test

bench: $(STAMP)
	$(VENV)/bin/landing-zone bench

lint: $(STAMP)
	$(PY) -m flake8 landing_zone msg_adapters test launch
	$(PY) -m mypy

clean:
	rm -rf $(VENV) build install log *.egg-info
