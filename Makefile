# Photon Lightmaps: `make demo` (set up + demo scene), `make test`, `make bench`.
PY := .venv/bin/python
export PHOTON_LIGHTMAPS_NUMBA_CACHE ?= $(CURDIR)/.numba_cache

.PHONY: setup demo test test-unit test-boundscheck test-first-run test-references test-quick warmup bench fuzz clean
setup: .venv/.stamp
.venv/.stamp: requirements.txt scripts/setup_venv.sh
	sh scripts/setup_venv.sh

# DEMO_ARGS: extra demo options (the test of this command passes tiny sizes).
DEMO_OUT ?= out/demo
DEMO_ARGS ?=
demo: setup
	$(PY) -m photon_lightmaps demo --out $(DEMO_OUT) $(DEMO_ARGS)

# The whole suite, and beside it a second lane: the bad-input and fuzz corpora
# with numba's bounds checking and the first-run tests (warm-up on an empty
# cache, the installed extension), each compiling into a kernel cache of its
# own, then the bakes compared with stored Cycles references. The first two
# are mostly compiling, which is one core's work, so side by side the lanes
# take little longer than the suite alone.
FIRST_RUN_TESTS = tests/test_first_run.py tests/test_extension.py
REFERENCE_TESTS = tests/test_bake_bias.py tests/test_boolean_bake.py
test: setup
	$(MAKE) -j2 --output-sync=target test-unit test-boundscheck test-first-run test-references

test-unit: setup
	$(PY) -m pytest -q --durations=25 $(addprefix --ignore=,$(FIRST_RUN_TESTS) $(REFERENCE_TESTS)) tests

test-first-run: setup
	$(PY) -m pytest -q --durations=5 $(FIRST_RUN_TESTS)

test-references: setup
	$(PY) -m pytest -q --durations=5 $(REFERENCE_TESTS)

# For iterating on the engine: its own tests, without Blender or subprocesses
# (the test files that import neither), on the kernel cache the suite keeps.
QUICK_TESTS = $(shell grep -L -E "bpy|subprocess|blender_session" tests/test_*.py)
test-quick: setup
	$(PY) -m pytest -q -x $(QUICK_TESTS)

# Compiles every kernel family now (engine/warmup.py), so the first render starts at once.
warmup: setup
	$(PY) -m photon_lightmaps warmup

test-boundscheck: setup
	NUMBA_BOUNDSCHECK=1 $(PY) -m pytest -q -p no:cacheprovider tests/test_bad_input.py tests/test_bad_input_blender.py tests/test_fuzz.py

fuzz: setup
	$(PY) -m benchmarks.fuzz --cases 10000 --json benchmarks/out/fuzz.json

bench: setup
	$(PY) benchmarks/bench_rays.py
	$(PY) benchmarks/bench_photons.py

clean:
	rm -rf out .numba_cache .pytest_cache
