# nurbscan: make demo | make test | make bench
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
NODE_DIR  := $(VENV)/node
VALIDATOR := $(NODE_DIR)/node_modules/gltf-validator/package.json

.PHONY: demo test bench lint clean

# Open3D (the fused mesh) needs the system library libusb-1.0 (Debian: apt-get install libusb-1.0-0).
$(STAMP): pyproject.toml
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

test: $(STAMP) $(VALIDATOR) lint
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) benchmarks/run.py

clean:
	rm -rf $(VENV) demo build *.egg-info src/*.egg-info .pytest_cache .ruff_cache
