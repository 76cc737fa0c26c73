# tpsv: two commands on a fresh machine —
#   make demo   (set up .venv, vectorize + render + magnify a bundled sample into out/)
#   make test   (set up .venv, run the test suite)
#   make fuzz N=100000 [SEED=0] [JOBS=2]   (structure-aware fuzz campaign; findings in fuzz-out/)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
SAMPLE ?= samples/chelsea.png
OUT    ?= out
N      ?= 1000
SEED   ?= 0
JOBS   ?= 1
FUZZ_OUT ?= fuzz-out

.PHONY: install test demo bench fuzz clean

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest

demo: $(STAMP)
	mkdir -p $(OUT)
	$(BIN)/tpsv vectorize $(SAMPLE) -o $(OUT)/demo.tpsv --labels $(SAMPLE:.png=-labels.png) --preview $(OUT)/demo-preview.png
	$(BIN)/tpsv info $(OUT)/demo.tpsv
	$(BIN)/tpsv render $(OUT)/demo.tpsv -o $(OUT)/demo-render.png
	$(BIN)/tpsv render $(OUT)/demo.tpsv -o $(OUT)/demo-x4.png --scale 4
	@echo "wrote $(OUT)/demo.tpsv, $(OUT)/demo-render.png, $(OUT)/demo-x4.png"

# Exit status 1 when any input crashed, hung (> 10 s) or passed 1 GB of RSS.
fuzz: $(STAMP)
	$(BIN)/python -m tests.fuzzing -n $(N) --seed $(SEED) --jobs $(JOBS) --out $(FUZZ_OUT) --progress

bench: $(STAMP)
	$(BIN)/tpsv bench --out bench-out

clean:
	rm -rf $(VENV) $(OUT) bench-out $(FUZZ_OUT) .pytest_cache
