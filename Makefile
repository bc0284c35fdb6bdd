# Two commands on a fresh machine: `make demo` and `make test` (see README.md).
# Both create .venv with Python 3.11 when it is missing and install the project into it.

PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# `make demo` runs the paper's Figure 3 and, next to it for a customer of their own, the
# examples of VVs that message each other and look at their pictures
# (examples/scenarios/messages-and-images.json); `make demo SCENARIO=FILE` runs FILE alone.
SCENARIO ?=
# More options of `manage.py demo` (`manage.py demo --help`), e.g. DEMO_ARGS=--access-log.
DEMO_ARGS ?=

.PHONY: demo test test-serial pytest lint check bench bench-simulate bench-service-levels bench-planner bench-load bench-burst bench-idle screenshots simulate-fig2 simulate-fig3 vendor clean

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "CPCC needs Python 3.11, found " + sys.version.split()[0] + " (set PYTHON=...)")'
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

demo: $(STAMP)
	$(PY) manage.py migrate --noinput
	$(PY) manage.py demo $(if $(SCENARIO),--scenario $(SCENARIO)) $(DEMO_ARGS)

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
	$(PY) -m mypy
	$(VENV)/bin/lint-imports --no-cache

check: $(STAMP)
	$(PY) manage.py check
	$(PY) manage.py makemigrations --check --dry-run

# The suite runs on TEST_WORKERS pytest-xdist workers (tests/parallel.py gives each a database,
# a Redis and a var folder of its own; --dist worksteal: a worker that runs out of tests takes
# some of the other's); `make test-serial` runs it in one process, for debugging.
# Both end with the suite's time (docs/testing.md says how to read it); PYTEST_ARGS adds options.
TEST_WORKERS ?= 2
PYTEST_ARGS ?=

test: $(STAMP)
	@start=$$(date +%s); \
	$(MAKE) --no-print-directory lint check && \
	$(MAKE) --no-print-directory pytest PYTEST_ARGS="-n $(TEST_WORKERS) --dist worksteal $(PYTEST_ARGS)"; \
	status=$$?; spent=$$(( $$(date +%s) - start )); \
	echo "make test: $$((spent / 60)) min $$((spent % 60)) s in all (lint, checks and tests), exit status $$status"; \
	exit $$status

test-serial: lint check
	$(MAKE) --no-print-directory pytest PYTEST_ARGS="-p no:xdist $(PYTEST_ARGS)"

pytest: $(STAMP)
	@test -x /usr/bin/chromium || echo "browser tests: skipped (no /usr/bin/chromium; apt-get install chromium)"
	$(PY) -m pytest $(PYTEST_ARGS)

simulate-fig2: $(STAMP)
	$(PY) manage.py simulate examples/scenarios/paper-fig2.json --speed 0

simulate-fig3: $(STAMP)
	$(PY) manage.py simulate examples/scenarios/paper-fig3.json --speed 0

bench: $(STAMP)
	$(PY) -m bench
	$(PY) -m bench.platform
	$(MAKE) bench-simulate
	$(PY) -m bench.live_map
	$(PY) -m bench.live_map --redis redis://127.0.0.1:6379/15
	$(PY) -m bench.map_browser
	$(MAKE) bench-planner
	$(MAKE) bench-load
	$(MAKE) bench-burst
	$(MAKE) bench-idle

# simulate on growing fleets (10 and 100 RVs, 10 VVs an RV, 10 tasks a VV; bench/simulate.py,
# ~15 minutes; BENCH_SIMULATE="--large" adds 1,000 RVs and 100,000 tasks, hours).
bench-simulate: $(STAMP)
	$(PY) -m bench.simulate $(BENCH_SIMULATE)

# A premium class (p95 30 s) on a busy 2x2 fleet that a bulk customer floods, alone, with the
# service classes and without, in three shapes and three seeds; issue 55's floor case by case
# (bench/service_levels.py, ~5 minutes; JSON in var/bench/).
bench-service-levels: $(STAMP)
	$(PY) -m bench.service_levels $(BENCH_SERVICE_LEVELS)

# The route planners on the demo5 protocol, overlapping areas, a survey and replanning times:
# tables for docs/benchmarks.md and docs/planner-latency.png (bench/planner.py, ~15 minutes).
bench-planner: $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,bench]'
	$(PY) -m bench.planner

# The REST API and the live map under load, the platform run as in production (DEBUG off,
# daphne, a worker per RV and GS) on the machine's PostgreSQL and Redis (127.0.0.1: database
# cpcc_bench_load, dropped and created anew; Redis db 14, flushed): bench/load.py, ~2 minutes.
bench-load: $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,bench]'
	$(PY) -m bench.load

# Many customers submitting at once: 20 bursts of 200 submissions from 16 clients to one daphne
# (DEBUG off) on the machine's PostgreSQL (database cpcc_bench_burst, dropped and created anew)
# and Redis (db 13, flushed), then SIGTERM under load: bench/submit_burst.py, ~2 minutes.
bench-burst: $(STAMP)
	$(PY) -m bench.submit_burst

# What an idle RV worker costs: one rvworker hosting 10 simulated RVs (and a gsworker) on a
# fresh SQLite database with no VV, its CPU over 30 s per hosted RV (bench/idle.py, ~1 minute;
# BENCH_IDLE="--rvs 40" or "--per-process" for other shapes).
bench-idle: $(STAMP)
	$(PY) -m bench.idle $(BENCH_IDLE)

# The README's pictures of the web front end, from the real pages of a demo run (Playwright
# driving /usr/bin/chromium): bench/screenshots.py, into docs/screenshots/.
screenshots: $(STAMP)
	$(PY) -m bench.screenshots

# Re-creates static/vendor/ (Leaflet, Leaflet-Geoman, CodeMirror, Chart.js) from npm; see
# static/vendor/README.md.
vendor:
	sh static/vendor/update.sh

clean:
	rm -rf $(VENV) var
