# The two commands of the README. Each creates the virtual environment and installs on first use
# (and again whenever pyproject.toml changes).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
STAMP := $(VENV)/.installed
# the project's bytecode, brought up to date whenever a module changes (below: compileall)
BYTECODE := $(VENV)/.bytecode
PACKAGES := rig drivers procedures reports tests benchmarks
SOURCES := $(shell find $(PACKAGES) -name '*.py')
# the numba kernels' on-disk cache, brought up to date after the install and whenever a module of rig/ or
# drivers/ changes (numba recompiles an edited kernel on its first call: 35.7 CPU-s in the first `rig measure`
# after a kernel edit, paid again by each pytest worker); unchanged kernels: 1.3 CPU-s, imports included
KERNELS := $(VENV)/.kernels
KERNEL_SOURCES := $(filter rig/% drivers/%,$(SOURCES))
BUILT := $(BYTECODE) $(KERNELS)  # what every command below needs
# pytest-xdist: 1.5 workers per core (tests/conftest.py's pytest_xdist_auto_num_workers: a third of the
# suite's worker time is waiting, which another worker's CPU fills; 3 workers on CI's 2 cores), each test
# file whole on one worker (module fixtures built once), in tests/conftest.py's order (the costliest first)
# rather than xdist's (most tests first)
PYTEST_PARALLEL ?= -n auto --dist loadfile --no-loadscope-reorder
# the test files to run (default: all); e.g. make test-load TESTS="tests/test_bcap_recovery.py"
TESTS ?=

.PHONY: certify test test-load test-lab test-times lint bench browser

# After the install, the project's bytecode (compileall), as pip writes it for every package it installs:
# where PYTHONDONTWRITEBYTECODE is set (as on this workplace's machines) each process would otherwise compile
# every project module it imports (0.2–0.3 CPU-s of a dry run's 1.9; test_cli_start + test_cli_logging, which
# start `rig` process after process: 17.6–18.1 → 16.4–16.7 CPU-s). A stale .pyc is never used: Python checks
# the source's time stamp; compileall rewrites only the changed modules'.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

$(BYTECODE): $(STAMP) $(SOURCES)
	$(VENV)/bin/python -m compileall -q $(PACKAGES)
	touch $(BYTECODE)

$(KERNELS): $(STAMP) $(KERNEL_SOURCES)
	$(VENV)/bin/python -m rig.warm_kernels  # numba's on-disk cache: a first run does not compile
	touch $(KERNELS)

certify: $(BUILT)
	$(VENV)/bin/rig certify

test: $(BUILT) browser
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy  # every package ([tool.mypy]: strict for rig.stereo, rig.config, rig.record, drivers)
	$(VENV)/bin/python -m pytest -q $(PYTEST_PARALLEL) $(TESTS)

# the same suite with a busy loop on every core (tests/conftest.py): timing must not depend on an idle machine
test-load: $(BUILT) browser
	RIG_TEST_LOAD=1 $(VENV)/bin/python -m pytest -q $(PYTEST_PARALLEL) $(TESTS)

# the cases that need the machine to themselves (the lab's full sweep: tests marked quiet_machine), one at a time
test-lab: $(BUILT)
	RIG_TEST_QUIET=1 $(VENV)/bin/python -m pytest -q -m quiet_machine tests/

# the suite once with per-test CPU recorded (tests/conftest.py, RIG_TEST_TIMES), summed per file into
# tests/file_costs.tsv: the order in which the xdist workers take the files (costliest first)
test-times: $(BUILT) browser
	rm -f .test-times.tsv
	RIG_TEST_TIMES=.test-times.tsv $(VENV)/bin/python -m pytest -q $(PYTEST_PARALLEL) $(TESTS)
	{ printf '# file\tcpu_s\twall_s (make test-times: per-test CPU incl. children, summed per file)\n'; \
	  awk -F'\t' '{split($$1, id, "::"); c[id[1]] += $$3; w[id[1]] += $$2} \
	    END {for (f in c) printf "%s\t%.1f\t%.1f\n", f, c[f], w[f]}' .test-times.tsv | sort -k2,2nr; \
	} > tests/file_costs.tsv

bench: $(BUILT)
	for b in benchmarks/*.py; do case $$b in benchmarks/fuzz_*) continue;; esac; \
		$(VENV)/bin/python $$b || exit 1; done  # fuzz_*.py run once, through benchmarks/fuzz.py

# The report's browser test (tests/test_reports_html_chromium.py) needs a headless Chromium. It is
# installed here, in its own announced step, when missing and this user may install Debian packages;
# otherwise the test skips and says why. No test installs anything itself.
browser:
	@if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  echo "make test: installing Chromium (Debian package 'chromium') for the report's browser test"; \
	  export DEBIAN_FRONTEND=noninteractive; \
	  { apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium fonts-dejavu-core \
	    >/dev/null; } || echo "make test: Chromium could not be installed; the browser test will skip"; \
	else echo "make test: no Chromium and no root to install it; the browser test will skip"; fi
