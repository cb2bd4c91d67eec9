# Everything installs from this project's own files. .venv (Python 3.11, bpy 4.5.4) runs the whole suite; each other
# supported Blender line gets its own environment, .venv-blender-X.Y (pyproject.toml's blender-X-Y extra), for the
# add-on tests. Interpreters are found by tools/find_python.sh; name one with e.g. make test PYTHON313=/path.
PYTHON311 ?= $$(tools/find_python.sh 3.11)
PYTHON313 ?= $$(tools/find_python.sh 3.13)
VENV := .venv
BIN := $(VENV)/bin
# The other supported lines and the Python each one's bpy module is built for.
LINES := 4.2 5.0 5.1 5.2
PYTHON_4.2 = $(PYTHON311)
PYTHON_5.0 = $(PYTHON311)
PYTHON_5.1 = $(PYTHON313)
PYTHON_5.2 = $(PYTHON313)
LINE_VENVS := $(LINES:%=.venv-blender-%)

.PHONY: demo blender-demo test test-fast bench docs extension clean

$(BIN)/.installed: pyproject.toml
	python=$(PYTHON311) && "$$python" -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev]'
	touch $@

.venv-blender-%/.installed: pyproject.toml
	python=$(PYTHON_$*) && "$$python" -m venv --clear .venv-blender-$*
	.venv-blender-$*/bin/pip install -q --upgrade pip
	.venv-blender-$*/bin/pip install -q -e '.[blender-$(subst .,-,$*)]'
	touch $@

demo: $(BIN)/.installed
	$(BIN)/python demo.py
	$(BIN)/python demo_blender.py

blender-demo: $(BIN)/.installed
	$(BIN)/python demo_blender.py

# The whole suite on .venv, then the add-on tests on every other line; a summary of each line at the end, and the
# exit status of the first line that failed.
test: $(BIN)/.installed $(LINE_VENVS:%=%/.installed)
	$(BIN)/python tools/test_lines.py $(VENV) $(LINE_VENVS)

# The inner loop: everything but the Blender tests and the ones marked slow, in under a minute.
test-fast: $(BIN)/.installed
	$(BIN)/python -m pytest -q -m "not slow and not blender"

# The benchmarks a user chooses by, measured again and written into docs/benchmarks.md and its plots into docs/images
# (about 15 minutes on a quiet 2-core machine). make bench BENCH_ARGS=--quick: a smoke run into out/bench-quick/.
bench: $(BIN)/.installed
	$(BIN)/python bench/report.py $(BENCH_ARGS)

# The API reference of lbc_core, from its docstrings (pdoc), into out/docs; it fails on a warning or a broken reference.
docs: $(BIN)/.installed
	$(BIN)/python tools/build_docs.py

# The extension zips and an extension repository (index.json) into dist/. Building needs only pip: .venv-build is a
# bare Python 3.11 environment, and tools/build_extension.py downloads the wheels and Blender's builder itself.
.venv-build/.installed:
	python=$(PYTHON311) && "$$python" -m venv --clear .venv-build
	.venv-build/bin/pip install -q --upgrade pip
	touch $@

# make extension PLATFORM=linux-x64 PYTHON=3.13 builds just that zip (and downloads just its wheels).
extension: .venv-build/.installed
	.venv-build/bin/python tools/build_extension.py $(if $(PLATFORM),--platform $(PLATFORM)) $(if $(PYTHON),--python $(PYTHON))

clean:
	rm -rf $(VENV) $(LINE_VENVS) .venv-build
