# Two commands for a new user: `make serve` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

$(BIN)/qem: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev]'
	touch $(BIN)/qem

# The web viewer's JavaScript packages (three.js, @msgpack/msgpack), pinned by the
# lockfile and served from node_modules: no bundler, no CDN.
WEB := client/web
$(WEB)/node_modules/.package-lock.json: $(WEB)/package-lock.json
	@command -v npm >/dev/null || { echo "npm not found: install Node.js >= 18 and npm" \
		"(Debian: apt-get install -y nodejs npm), then run make install again" >&2; exit 1; }
	cd $(WEB) && npm ci --no-audit --no-fund
	touch $@

# The viewer's WebAssembly split decoder, compiled from C by the dev extra's ziglang.
$(WEB)/js/refine.wasm: $(WEB)/wasm/refine.c client/build_wasm.py $(BIN)/qem
	$(BIN)/python client/build_wasm.py

.PHONY: install serve test lint bench fuzz
install: $(BIN)/qem $(WEB)/node_modules/.package-lock.json $(WEB)/js/refine.wasm

serve: install
	$(BIN)/qem serve --demo

test: install
	$(BIN)/ruff check .
	$(BIN)/pytest

bench: install
	$(BIN)/pip install -q -e '.[dev,bench]'
	$(BIN)/python -m bench.run_all

# The fuzz harness (fuzz/): every reader and decoder, FUZZ_SECONDS each; findings are
# saved under fuzz/findings/ and make the target fail.
FUZZ_SECONDS ?= 60
fuzz: install
	$(BIN)/python -m fuzz --seconds $(FUZZ_SECONDS)
