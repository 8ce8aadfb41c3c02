#!/usr/bin/env bash
# End-to-end check: start serve.sh on a spare loopback port, send a request file
# RUNS times, print the first reply and the timings, then stop the server.
# Usage: smoke.sh [PORT] [REQUEST.json]   (defaults: 8099, sample-request.json; RUNS=3)
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
PORT="${1:-8099}"
REQ="${2:-$HERE/sample-request.json}"
RUNS="${RUNS:-3}"

work="$(mktemp -d /tmp/local-llm-smoke.XXXXXX)"
t0=$(date +%s%N)
"$HERE/serve.sh" "$PORT" >"$work/stdout" 2>"$work/stderr" &
pid=$!
cleanup() {
    kill -TERM "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT

for _ in $(seq 1 600); do
    [ -s "$work/stdout" ] && break
    if ! kill -0 "$pid" 2>/dev/null; then cat "$work/stderr" >&2; echo "smoke: server exited" >&2; exit 1; fi
    sleep 0.1
done
[ -s "$work/stdout" ] || { cat "$work/stderr" >&2; echo "smoke: server not ready after 60 s" >&2; exit 1; }
base="$(head -n1 "$work/stdout")"
echo "smoke: server ready at $base after $(( ($(date +%s%N) - t0) / 1000000 )) ms (process start to first request)"
sed 's/^/smoke: [server] /' "$work/stderr"

curl -sS -f "$base/health" >/dev/null
for i in $(seq 1 "$RUNS"); do
    secs=$(curl -sS -o "$work/reply.$i.json" -w '%{time_total}' \
        -H 'content-type: application/json' --data @"$REQ" "$base/v1/chat/completions")
    usage=$(node -e 'const r=JSON.parse(require("fs").readFileSync(process.argv[1],"utf8"));
        if (r.error) { console.log("ERROR " + JSON.stringify(r.error)); process.exit(1); }
        const u=r.usage; console.log(`prompt_tokens=${u.prompt_tokens} completion_tokens=${u.completion_tokens} finish_reason=${r.choices[0].finish_reason}`);' \
        "$work/reply.$i.json")
    echo "smoke: run $i: ${secs} s, $usage"
done
echo "smoke: reply of run 1:"
cat "$work/reply.1.json"; echo
