# nurbscan: make demo | make test | make bench
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
NODE_DIR  := $(VENV)/node
VALIDATOR := $(NODE_DIR)/node_modules/gltf-validator/package.json

.PHONY: demo test bench lint clean

# Open3D's wheel links libusb-1.0 (Debian's package libusb-1.0-0), which a fresh machine may lack.
$(STAMP): pyproject.toml
	@if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then \
	  if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
	    (apt-get update -qq && apt-get install -y -qq libusb-1.0-0 >/dev/null) \
	      || echo "libusb-1.0-0 could not be installed: open3d will not import"; \
	  else echo "libusb-1.0-0 is missing (sudo apt-get install libusb-1.0-0): open3d needs it"; fi; \
	fi
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# Khronos glTF-Validator (npm), used by the tests to check exported .glb files.
$(VALIDATOR):
	@if command -v npm >/dev/null; then \
	  npm install --prefix $(NODE_DIR) --no-audit --no-fund --silent gltf-validator@2.0.0-dev.3.10; \
	else echo "npm not found: the glTF-Validator test will be skipped"; fi

demo: $(STAMP)
	$(VENV)/bin/nurbscan demo -o demo

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks

# Two pytest workers, each test file in one of them (its module fixtures built once): the
# suite took 17 min 19 s in one process and 10 min 52 s so on the 2-core machine, each
# worker's peak memory 2.4 GB. `make test TEST_WORKERS=0` runs it in one process.
TEST_WORKERS ?= 2

test: $(STAMP) $(VALIDATOR) lint
	$(PY) -m pytest -q $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

bench: $(STAMP)
	$(PY) benchmarks/run.py

clean:
	rm -rf $(VENV) demo build *.egg-info src/*.egg-info .pytest_cache .ruff_cache
