# The two commands of the README:
#   make run    set up, then run the main job (no hardware: the embedded simulated bench)
#   make test   set up, then run every test (cargo test, then pytest)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
CARGO_MANIFEST := rtcore/Cargo.toml
# The extension is abi3 (admittance/_rtcore.abi3.so); a version-specific build left over from
# before would be imported first and shadow every rebuild, so it goes.
STALE_EXT := admittance/_rtcore.cpython-*.so

.PHONY: setup ext run test test-rust test-stub test-python test-thorough bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml $(shell find rtcore -name '*.rs' -o -name 'Cargo.toml' -o -name '*.toml' 2>/dev/null | grep -v target)
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip maturin
	$(BIN)/pip install --quiet $$($(BIN)/python -c "import tomllib;p=tomllib.load(open('pyproject.toml','rb'))['project'];print(' '.join(repr(d) for d in p['dependencies']+p['optional-dependencies']['test']))" | tr -d "'")
	rm -f $(STALE_EXT)
	$(BIN)/maturin develop --release --quiet
	touch $(STAMP)

# Rebuild only the extension, in place (admittance/_rtcore.abi3.so), without touching the venv.
ext:
	rm -f $(STALE_EXT)
	$(BIN)/maturin develop --release --skip-install --quiet

run: setup
	$(BIN)/admittance run

test: setup test-rust test-stub test-python

# The typed boundary: the stub admittance/_rtcore.pyi against the built extension (every name and
# signature), and the loop's configuration builder against the stub's types.
test-stub: setup
	$(BIN)/python -m mypy.stubtest admittance._rtcore
	$(BIN)/python -m mypy --follow-imports=silent --ignore-missing-imports admittance/daemon/loopconfig.py admittance/loop_config.py

test-rust:
	cargo test --manifest-path $(CARGO_MANIFEST) --workspace --exclude admittance-py

test-python: setup
	MPLBACKEND=Agg $(BIN)/python -m pytest

# A bug hunt, not part of `make test`: every property test with 20x its examples.
test-thorough: setup
	HYPOTHESIS_SCALE=20 MPLBACKEND=Agg $(BIN)/python -m pytest -m "not hil and not slow"

bench: setup
	for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) rtcore/target
