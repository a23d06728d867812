# Two-command quick start:  `make run` (service + demo)  and  `make test`.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install run test test-all test-browser test-reliability test-ray bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e '.[test]' --config-settings editable_mode=compat
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/siva serve --demo --host 127.0.0.1 --port $${PORT:-8000} --data-dir $${SIVA_DATA_DIR:-./siva-data}

test: $(STAMP)
	$(BIN)/python -m pytest -q

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
	$(BIN)/pip install -q 'ray==2.60.0'
	scripts/ray-local-cluster.sh stop
	scripts/ray-local-cluster.sh start
	SIVA_EXECUTOR=ray SIVA_RAY_ADDRESS=127.0.0.1:$${SIVA_RAY_PORT:-6390} \
	  $(BIN)/python -m pytest -q -m 'not slow' $(RAY_TESTS); \
	  rc=$$?; scripts/ray-local-cluster.sh stop; exit $$rc

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) siva-data .pytest_cache

.PHONY: constraints docker-smoke

# docker/constraints.txt: the versions of the working venv, used by the Docker build
constraints: $(STAMP)
	( sed -n '1,2p' docker/constraints.txt; $(BIN)/pip freeze --exclude-editable ) > docker/constraints.new
	mv docker/constraints.new docker/constraints.txt

# build the image on $(BASE_IMAGE) and smoke-test the container (docker/smoke.sh says how)
docker-smoke:
	bash docker/smoke.sh
