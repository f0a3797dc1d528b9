# Set-up and the two everyday commands. `make sim` and `make test` create .venv on first use.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python

.PHONY: sim test benchmark clean browser

# setuptools announces every editable install of a package-dir mapping ("Editable installation. Please be
# careful with folders ..."), an information-only note, not a problem: silenced by its message only
$(VENV)/.installed: export PYTHONWARNINGS = ignore:Editable installation
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[sim,ur,modbus,canopen,report,plc,test]'
	touch $@

# Identify the payload of the simulated EC66 end to end (real JSON-RPC protocol on loopback).
sim: $(VENV)/.installed
	$(VENV)/bin/payload-agent run --robot configs/sim-ec66.yaml --yes

# pytest-xdist workers: each has its own state folder (tests/conftest.py), simulated controllers bind
# ephemeral ports or a free 127.0.0.x, so the files run side by side; a file stays on one worker, in its own
# order (its module-scoped simulators and CLI runs are built once, as in a serial run). Files go out slowest
# first (tests/conftest.py SLOWEST_FIRST): --no-loadscope-reorder keeps xdist from sorting them by test count
# Three workers on two cores: with two, a quiet 2-core machine was 30 % idle (session 21: 140 % of CPU), the
# workers waiting for simulated controllers' real-time motion, their processes' start and the browser; a third
# fills those waits (session 22, docs/benchmarks.md). TEST_WORKERS=2 make test keeps the old way.
TEST_WORKERS ?= 3
# A worker that dies in native code can leave xdist's controller waiting for ever (seen once, session 17): the
# suite is ended after 30 min (about 6x its time on a loaded 2-core machine) so that it fails, saying so, not hangs
test: $(VENV)/.installed browser
	@timeout --kill-after=30 1800 $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder; \
	  rc=$$?; if [ $$rc -eq 124 ] || [ $$rc -eq 137 ]; then \
	  echo "make test: the test suite did not finish within 30 min and was stopped (a hung or crashed worker?)" >&2; fi; \
	  exit $$rc

# The report's screenshot tests render in headless Chromium (Debian package `chromium`): installed
# here when missing and we are root with apt-get; otherwise those tests skip (CI makes them fail).
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing Chromium (Debian package chromium) for the report screenshot tests"; \
	    DEBIAN_FRONTEND=noninteractive timeout 600 apt-get update -qq && \
	    DEBIAN_FRONTEND=noninteractive timeout 900 apt-get install -y -qq --no-install-recommends chromium \
	      || echo "WARNING: could not install chromium; the browser tests will not run" >&2; \
	  else echo "WARNING: Chromium missing and cannot be installed here; the browser tests will not run" >&2; fi; }

benchmark: $(VENV)/.installed
	$(PY) -m benchmarks.accuracy

clean:
	rm -rf $(VENV) runs state .pytest_cache
