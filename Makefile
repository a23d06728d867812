# Two-command quick start:  `make run` (service + demo)  and  `make test`.
# Installs come from requirements.lock (every package pinned, with its sha256; `make lock`
# refreshes it), so two fresh venvs are the same venv (docs/reliability.md, "locked installs").
PY ?= $(shell command -v python3.11 || echo python3)
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
LOCK := requirements.lock
RAY_LOCK := requirements-ray.lock

.PHONY: install run test test-heavy test-all test-browser test-reliability test-ray test-platform bench \
	clean lock

$(STAMP): pyproject.toml $(LOCK)
	@$(PY) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || \
	  { echo "$(LOCK) is for CPython 3.11 (found $$($(PY) --version)): make PY=python3.11"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --require-hashes --no-deps -r $(LOCK)
	$(BIN)/pip install -q --no-deps --no-build-isolation -e . --config-settings editable_mode=compat
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/siva serve --demo --host 127.0.0.1 --port $${PORT:-8000} --data-dir $${SIVA_DATA_DIR:-./siva-data}

# --durations: the slowest tests named in every CI log (the default suite's 10-minute budget)
test: $(STAMP)
	$(BIN)/python -m pytest -q --durations=15

# the end-to-end runs kept out of the default suite's 10-minute budget (CI runs them next)
test-heavy: $(STAMP)
	$(BIN)/python -m pytest -q -m heavy --durations=10

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m ''

# the dashboard in headless Chromium (Debian's chromium + chromium-driver; run as root)
test-browser: $(STAMP)
	@command -v chromium >/dev/null && command -v chromedriver >/dev/null || \
	  (apt-get update && apt-get install -y chromium chromium-driver)
	$(BIN)/python -m pytest -q tests/service/test_dashboard.py

# the reliability suite, slow parts included (tmpfs tests need root; see docs/reliability.md)
test-reliability: $(STAMP)
	$(BIN)/python -m pytest -q -m '' tests/reliability

# the service's API tests with SIVA_EXECUTOR=ray on a local two-node Ray cluster (loopback),
# plus the Ray executor's own tests (actor kill -9, placement); docs/fleet.md
RAY_TESTS := tests/service/test_api.py tests/service/test_convergence.py \
	tests/service/test_restart.py tests/service/test_replay.py tests/service/test_bad_input.py \
	tests/service/test_ray_executor.py
test-ray: $(STAMP)
	$(BIN)/pip install -q --require-hashes --no-deps -r $(RAY_LOCK)
	scripts/ray-local-cluster.sh stop
	scripts/ray-local-cluster.sh start
	SIVA_EXECUTOR=ray SIVA_RAY_ADDRESS=127.0.0.1:$${SIVA_RAY_PORT:-6390} \
	  $(BIN)/python -m pytest -q -m 'not slow' $(RAY_TESTS); \
	  rc=$$?; scripts/ray-local-cluster.sh stop; exit $$rc

# the replay tests on a second platform: torch's portable kernels (ATEN_CPU_CAPABILITY=default)
# instead of this CPU's, so a test bound to one machine's arithmetic fails in CI (issue 19)
test-platform: $(STAMP)
	ATEN_CPU_CAPABILITY=default $(BIN)/python -m pytest -q tests/service/test_replay.py \
	  tests/service/test_mcap_log.py

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) $(LOCK_VENV) siva-data .pytest_cache

.PHONY: docker-smoke

# Re-resolve the locks (new dependencies in pyproject.toml; UPGRADE=1: newest versions of
# everything). pip-tools lives in its own venv so that $(VENV) is exactly the lock. torch
# resolves to the CPU wheel (2.13.0+cpu) only where pip finds it (pip's find-links, e.g.
# /opt/wheels, or PIP_EXTRA_INDEX_URL=https://download.pytorch.org/whl/cpu); the last step
# refuses a lock that pulled CUDA packages instead.
LOCK_VENV := .venv-lock
LOCK_FLAGS := --generate-hashes --allow-unsafe --strip-extras --no-emit-index-url \
	--no-emit-find-links $(if $(UPGRADE),--upgrade)
lock:
	$(PY) -m venv $(LOCK_VENV)
	$(LOCK_VENV)/bin/pip install -q 'pip-tools==7.6.2'
	$(LOCK_VENV)/bin/pip-compile -q $(LOCK_FLAGS) --extra test -o $(LOCK) pyproject.toml
	$(LOCK_VENV)/bin/pip-compile -q $(LOCK_FLAGS) --extra test --extra ray -c $(LOCK) \
	  -o $(RAY_LOCK) pyproject.toml
	@! grep -iE '^(nvidia-|triton|cuda)' $(LOCK) $(RAY_LOCK) || \
	  { echo "CUDA packages in the lock: make the CPU torch wheel reachable (see above)"; exit 1; }

# build the image on $(BASE_IMAGE) and smoke-test the container (docker/smoke.sh says how)
docker-smoke:
	bash docker/smoke.sh
