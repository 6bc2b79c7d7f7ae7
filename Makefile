# rsfm: the two entry points of the README.
#   make demo   install missing Debian packages, build (Release), run the main job on its default
#   make test   install missing Debian packages, build (Release), run every test through ctest
BUILD ?= build
OUT ?= out
JOBS ?= $(shell nproc 2>/dev/null || echo 2)

.PHONY: all deps configure build demo test bench clean

all: build

deps:
	bash scripts/install-deps.sh

configure: deps
	cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=Release

build: configure
	cmake --build $(BUILD) -j$(JOBS)

demo: build
	./$(BUILD)/rsfm experiment table1 --out $(OUT)
	@echo
	@sed -n '/^| formulation | noise px | m_t/,/^$$/p' $(OUT)/table1.md
	@sed -n '/^| noise px | plane sigma_t/,/^$$/p' $(OUT)/table1.md
	@echo "Report: $(OUT)/table1.md, $(OUT)/table1.csv, $(OUT)/fig1.png, $(OUT)/fig1.svg"

test: build
	cd $(BUILD) && ctest --output-on-failure -j$(JOBS)

bench: build
	./$(BUILD)/rsfm_bench --benchmark_counters_tabular=true

clean:
	rm -rf $(BUILD)
