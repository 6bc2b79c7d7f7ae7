# rsfm: the two entry points of the README.
#   make demo   install missing Debian packages, build (Release), run the main job on its default:
#               rsfm run on a rendered sequence (evaluated against its truth), on opencv-doc's
#               box.mp4 and on the ViSP cube sequence (scripts/demo.sh)
#   make test   install missing Debian packages, build (Release), run every test through ctest
BUILD ?= build
OUT ?= out
JOBS ?= $(shell nproc 2>/dev/null || echo 2)

.PHONY: all deps configure build demo experiments regimes test test-sanitize fuzz-build fuzz bench clean

all: build

deps:
	bash scripts/install-deps.sh

configure: deps
	cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=Release

build: configure
	cmake --build $(BUILD) -j$(JOBS)

demo: build
	bash scripts/demo.sh $(BUILD) $(OUT)

# The papers' synthetic experiments (issues 2, 3, 5): Table 1, the box scene, two objects, patches.
experiments: build
	./$(BUILD)/rsfm experiment table1 --out $(OUT)/table1
	./$(BUILD)/rsfm experiment planes --out $(OUT)/planes
	./$(BUILD)/rsfm experiment two-object --out $(OUT)/two-object
	./$(BUILD)/rsfm experiment patches --out $(OUT)/patches

# The regime suite's scoreboard (issue 12; docs/regimes.md): 35 rendered sequences and the real
# rows with default options, into $(OUT)/regimes (renderings cached in ~/.cache/rsfm/regimes).
regimes: build
	./$(BUILD)/rsfm bench regimes --out $(OUT)/regimes

test: build
	cd $(BUILD) && ctest --output-on-failure -j$(JOBS)

# The whole suite again under AddressSanitizer + UndefinedBehaviorSanitizer (issue 17), in its own
# build directory; any finding fails the test that met it. Leak checking is off (LeakSanitizer
# needs ptrace, which containers often refuse).
test-sanitize: deps
	cmake -S . -B $(BUILD)-sanitize -DCMAKE_BUILD_TYPE=Release -DRSFM_SANITIZE=ON -DRSFM_BUILD_BENCH=OFF -DRSFM_BUILD_PYTHON=OFF
	cmake --build $(BUILD)-sanitize -j$(JOBS)
	cd $(BUILD)-sanitize && ASAN_OPTIONS=detect_leaks=0:abort_on_error=0 UBSAN_OPTIONS=print_stacktrace=1 \
	  ctest --output-on-failure -j$(JOBS)

# libFuzzer on every reader (issue 17; tests/fuzz/README.md): clang builds the fuzz targets in
# $(BUILD)-fuzz, then each runs FUZZ_SECONDS (default 60). `make test` replays their corpora.
FUZZ_SECONDS ?= 60
fuzz-build: deps
	command -v clang++ >/dev/null 2>&1 || apt-get install -y -q --no-install-recommends -o DPkg::Lock::Timeout=600 clang
	CC=clang CXX=clang++ cmake -S . -B $(BUILD)-fuzz -DCMAKE_BUILD_TYPE=Release -DRSFM_FUZZ=ON -DRSFM_BUILD_BENCH=OFF -DRSFM_BUILD_PYTHON=OFF
	cmake --build $(BUILD)-fuzz -j$(JOBS) --target rsfm_fuzz_all

fuzz: fuzz-build
	bash tests/fuzz/run.sh $(BUILD)-fuzz $(FUZZ_SECONDS)

bench: build
	./$(BUILD)/rsfm_bench --benchmark_counters_tabular=true
	bash bench/run_fps.sh $(BUILD)

clean:
	rm -rf $(BUILD)
