# Everything installs into .venv at the repo root from this project's own files.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo blender-demo test bench extension clean

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev]'
	touch $@

demo: $(BIN)/.installed
	$(BIN)/python demo.py
	$(BIN)/python demo_blender.py

blender-demo: $(BIN)/.installed
	$(BIN)/python demo_blender.py

test: $(BIN)/.installed
	$(BIN)/python -m pytest -q

bench: $(BIN)/.installed
	$(BIN)/python bench/run.py
	$(BIN)/python bench/bench_mesher.py

extension: $(BIN)/.installed
	$(BIN)/python tools/build_extension.py

clean:
	rm -rf $(VENV)
