#!/usr/bin/env bash
# Builds the native core with AddressSanitizer + UndefinedBehaviorSanitizer (any report aborts)
# and runs its C tests; the core is plain C with no Python, so it is tested here on its own.
# The core is every .c file of native/ except the Python bindings (pymodule.c, py/).
set -euo pipefail
cd "$(dirname "$0")/.."
# one binary per run: several worktrees building at once into one path ran each other's binaries
out=${TMPDIR:-/tmp}/tearcloth_native_tests.$$
trap 'rm -f "$out" "$out.collide"' EXIT
core=$(ls *.c | grep -v '^pymodule\.c$')
# shellcheck disable=SC2086
cc -std=c17 -g -O1 -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all \
   -DTC_NO_CLONES -Wall -Wextra -Wno-unused-parameter -I. \
   $core tests/test_core.c -lm -o "$out"
# once per kernel of the solver's matrix-vector product (fem.c picks it from TEARCLOTH_SIMD; one the
# CPU lacks falls back to the best it has, so every machine runs all it can). The first kernel runs
# every test; the others run --kernels: every test but test_strip_and_tear and test_amg, ~90 % of a
# pass (25 s each here). Those two exercise no kernel code that the kept tests do not compare across
# kernels within 1e-12 (the product, the CG iterates with contacts, the multigrid cycle).
case "$(uname -m)" in
    aarch64 | arm64) kernels="neon scalar" ;;
    *) kernels="avx2 scalar sse2" ;;
esac
mode=""
for kernel in $kernels; do
    echo "kernel $kernel${mode:+ ($mode)}:"
    # shellcheck disable=SC2086
    TEARCLOTH_SIMD=$kernel ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 "$out" $mode
    mode=--kernels
done
# The collision kernels (native/collide/, all but their Python bindings) and their C tests: a
# deforming cloth over a moving body, before and after a tear, and bad indices.
collide=$(ls collide/*.c | grep -v '^collide/pymodule\.c$')
# shellcheck disable=SC2086
cc -std=c17 -g -O1 -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all \
   -Wall -Wextra -Wno-unused-parameter -I. -Icollide \
   $collide tests/test_collide.c -lm -o "$out.collide"
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 "$out.collide"
