#!/usr/bin/env bash
# Runs every cargo-fuzz target of fuzz/ in turn, one at a time, for SECONDS_PER_TARGET seconds
# each (default 600), under `nice -n 19`. Prints each target's execution count and the path of
# any crash, timeout or out-of-memory input; exits non-zero if one was found.
#
#   tools/fuzz/run.sh [SECONDS_PER_TARGET] [TARGET...]
#
# With RUNS=N in the environment a target also stops after N executions (issue 18's bar is
# 10^6 executions or 10 minutes, whichever comes first: RUNS=1000000 tools/fuzz/run.sh 600).
#
# Needs a nightly toolchain and cargo-fuzz (`cargo +nightly install cargo-fuzz --locked`).
# New crashes land in fuzz/artifacts/<target>/; minimise one with
# `cargo +nightly fuzz tmin -s none <target> <file>`, save it under
# tests/data/fuzz-regressions/<target>/ (replayed by `cargo test --test integration
# fuzz_regressions` and `cargo test -p activemap-llm --test fuzz_regressions`) and fix the parser.
set -uo pipefail
cd "$(dirname "$0")/../../fuzz"

seconds="${1:-600}"
shift || true
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cargo +nightly fuzz list)
fi
# Without AddressSanitizer: the parsers are safe Rust, and uninstrumented code runs several
# times faster. Overflow checks and debug assertions are on (fuzz/Cargo.toml).
flags=(-s none)

nice -n 19 cargo +nightly fuzz build "${flags[@]}" || exit 2
found=0
for target in "${targets[@]}"; do
    log="target/fuzz-${target}.log"
    rm -f fuzz-0.log
    before=$(find "artifacts/${target}" -type f 2>/dev/null | wc -l)
    echo "== ${target}: ${seconds} s"
    nice -n 19 cargo +nightly fuzz run "${flags[@]}" "${target}" -- \
        -max_total_time="${seconds}" ${RUNS:+-runs="${RUNS}"} -jobs=1 -workers=1 -timeout=10 -rss_limit_mb=2048 \
        -print_final_stats=1 >"${log}" 2>&1
    status=$?
    # With -jobs, libFuzzer's own output goes to fuzz-<job>.log in the working directory.
    if [ -f fuzz-0.log ]; then
        cat fuzz-0.log >>"${log}" && rm -f fuzz-0.log
    fi
    execs=$(grep -o '^stat::number_of_executed_units: *[0-9]*' "${log}" | grep -o '[0-9]*$' | tail -1)
    last=$(grep -E '^#[0-9]+' "${log}" | tail -1)
    echo "   executions: ${execs:-unknown} (${last:-no status line})"
    after=$(find "artifacts/${target}" -type f 2>/dev/null | wc -l)
    if [ "${status}" -ne 0 ] || [ "${after}" -gt "${before}" ]; then
        found=1
        echo "   FAILED (exit ${status}); log: fuzz/${log}"
        grep -E 'Test unit written to|panicked at' "${log}" | sed 's/^/   /'
    fi
done
exit "${found}"
