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

.PHONY: setup ext run test test-rust test-stub test-python test-thorough bench wheel sdist clean

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
# signature), and the loop's configuration builder, the supervisor and its backends against the
# stub's types (backends.py: both force readers, Python and Rust, against force_reader.ForceStream).
test-stub: setup
	$(BIN)/python -m mypy.stubtest admittance._rtcore
	$(BIN)/python -m mypy --follow-imports=silent --ignore-missing-imports admittance/daemon/loopconfig.py admittance/loop_config.py admittance/daemon/supervisor.py admittance/daemon/backends.py

test-rust:
	cargo test --manifest-path $(CARGO_MANIFEST) --workspace --exclude admittance-py

test-python: setup
	MPLBACKEND=Agg $(BIN)/python -m pytest

# A bug hunt, not part of `make test`: every property test with 20x its examples.
test-thorough: setup
	HYPOTHESIS_SCALE=20 MPLBACKEND=Agg $(BIN)/python -m pytest -m "not hil and not slow"

bench: setup
	for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# The portable wheel: linked by zig (ziglang from PyPI) against glibc 2.17, so it installs on any
# manylinux2014 system (CentOS 7 onwards, Debian 9+, Ubuntu 18.04+); maturin refuses to tag it if
# the extension needs a newer symbol. MANYLINUX selects another policy (e.g. manylinux_2_28).
MANYLINUX ?= manylinux2014
wheel: setup
	$(BIN)/pip install --quiet 'ziglang>=0.13'
	CARGO_ZIGBUILD_PYTHON_PATH=$(abspath $(BIN))/python $(BIN)/maturin build --release --zig --compatibility $(MANYLINUX) --out dist

# The source distribution: builds on any Linux (aarch64 too: a Raspberry Pi, a Jetson) with a Rust
# toolchain, by `pip install dist/admittance-*.tar.gz` (README, Install).
sdist: setup
	$(BIN)/maturin sdist --out dist

clean:
	rm -rf $(VENV) rtcore/target
