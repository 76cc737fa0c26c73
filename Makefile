# tpsv: two commands on a fresh machine —
#   make demo   (set up .venv, vectorize + render + magnify a bundled sample into out/)
#   make test   (set up .venv, run the test suite)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
SAMPLE ?= samples/chelsea.png
OUT    ?= out

.PHONY: install test demo bench clean

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

bench: $(STAMP)
	$(BIN)/tpsv bench --out bench-out

clean:
	rm -rf $(VENV) $(OUT) bench-out .pytest_cache
