# Photon Lightmaps: `make demo` (set up + demo scene), `make test`, `make bench`.
PY := .venv/bin/python
export PHOTON_LIGHTMAPS_NUMBA_CACHE ?= $(CURDIR)/.numba_cache

.PHONY: setup demo test bench clean
setup: .venv/.stamp
.venv/.stamp: requirements.txt scripts/setup_venv.sh
	sh scripts/setup_venv.sh

demo: setup
	$(PY) -m photon_lightmaps demo --out out/demo

test: setup
	$(PY) -m pytest -q tests

bench: setup
	$(PY) benchmarks/bench_rays.py
	$(PY) benchmarks/bench_photons.py

clean:
	rm -rf out .numba_cache .pytest_cache
