# Developer commands (CONTRIBUTING.md), in the activated virtual environment.
PYTHON ?= python

.PHONY: lint types fast e2e slow test base-install ci

lint:  ## ruff and the import contracts
	ruff check .
	lint-imports

types:  ## mypy over both packages (about a minute)
	mypy

fast:  ## the unit tier: no process, router, simulator or browser
	$(PYTHON) -m pytest -q -m unit

e2e:  ## processes, Zenoh, the simulator, the browser, real firmware
	$(PYTHON) -m pytest -q -m e2e

slow:  ## in memory, but long
	$(PYTHON) -m pytest -q -m slow

test:  ## every tier (about 20 minutes on a quiet 2-core machine)
	$(PYTHON) -m pytest -q

base-install:  ## pip install . with no extra in /tmp: serve --check and evaluate
	.ci/base-install

ci:  ## what CI runs: a fresh environment, then all of the above
	.ci/run
