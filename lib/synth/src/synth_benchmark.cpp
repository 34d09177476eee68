#include <benchmark/benchmark.h>
static void BM_Empty(benchmark::State& s) { for (auto _ : s) {} }
BENCHMARK(BM_Empty);
