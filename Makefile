# Set-up and the two everyday commands. `make sim` and `make test` create .venv on first use.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python

.PHONY: sim test benchmark clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[sim,ur,modbus,canopen,report,test]'
	touch $@

# Identify the payload of the simulated EC66 end to end (real JSON-RPC protocol on loopback).
sim: $(VENV)/.installed
	$(VENV)/bin/payload-agent run --robot configs/sim-ec66.yaml --yes

test: $(VENV)/.installed
	$(PY) -m pytest -q

benchmark: $(VENV)/.installed
	$(PY) -m benchmarks.accuracy

clean:
	rm -rf $(VENV) runs state .pytest_cache
