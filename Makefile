# artcal_ros: make demo | make test | make bench. Each bootstraps .venv on first use.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.bootstrapped

.PHONY: demo test lint unit integration replay bench clean-venv sample-bag

$(STAMP): requirements.txt setup.py setup.cfg package.xml
	@command -v $(PYTHON) >/dev/null || { echo "$(PYTHON) is needed (the ROS 2 kilted wheels are built for Python 3.11)"; exit 2; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check --upgrade pip setuptools wheel
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	@echo "installing artcal_ros; the install compiles the detector's kernels (about half a minute)"
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m artcal_ros.ros.demo --bag bags/sample --params config/calibrator.yaml

lint: $(STAMP)
	$(VENV)/bin/ruff check artcal_ros test bench launch setup.py
	$(VENV)/bin/mypy artcal_ros

unit: $(STAMP)
	$(PY) -m pytest -q test/unit

integration: $(STAMP)
	$(PY) -m pytest -q test/integration test/replay

test: lint $(STAMP)
	$(PY) -m pytest -q test

bench: $(STAMP)
	$(PY) -m bench

sample-bag: $(STAMP)
	$(PY) -m bench.make_sample_bag

clean-venv:
	rm -rf $(VENV)
