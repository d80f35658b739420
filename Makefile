# Developer commands (CONTRIBUTING.md), in the activated virtual environment.
PYTHON ?= python
# pytest-xdist workers; --dist loadscope keeps a module's tests (and its module-scoped
# fixtures: a flight, a fleet, a plan) on one worker; the unit tier has none worth it and
# balances better test by test.
JOBS ?= 2
PYTEST = $(PYTHON) -m pytest -q -n $(JOBS) --dist loadscope

.PHONY: lint types fast slow integration system simulators browsers test base-install ci

lint:  ## ruff and the import contracts
	ruff check .
	lint-imports

types:  ## mypy over both packages (about a minute)
	mypy

fast:  ## tests/unit: in memory and quick (about a minute on 2 cores)
	$(PYTHON) -m pytest -q -n $(JOBS) tests/unit

slow:  ## tests/slow: in memory, but long
	$(PYTEST) tests/slow

integration:  ## tests/integration: pdcov commands and other processes
	$(PYTEST) tests/integration

system:  ## tests/system: Zenoh routers and sessions, several daemons
	$(PYTEST) tests/system

simulators:  ## tests/simulators: JSBSim flights, the real ArduCopter SITL, MAVSDK
	$(PYTEST) tests/simulators

browsers:  ## tests/browsers: chromium
	$(PYTEST) tests/browsers

test:  ## every tier, in parallel (CONTRIBUTING.md "Tests" for the time)
	$(PYTEST)

base-install:  ## pip install . with no extra in /tmp: serve --check and evaluate
	.ci/base-install

ci:  ## what CI runs: a fresh environment, then all of the above
	.ci/run
