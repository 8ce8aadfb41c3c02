#!/usr/bin/env bash
# Soak run (issue 18): EPISODES short exploration episodes back to back through ONE machine
# daemon, sampling after each the daemon's open file descriptors and resident memory and the
# entries in /dev/shm. Prints one row per episode and exits non-zero when an episode failed or
# when descriptors or /dev/shm entries grew between the second episode and the last (the first
# one warms caches up).
#
#   tools/soak/run.sh [EPISODES=10] [STEPS=60]
#
# Uses target/release/activemap (build it first) or $ACTIVEMAP. Episodes: dataflow.yaml on a
# small procedural house (house:3, 2 rooms) at 64x64, STEPS steps each, on loopback.
set -euo pipefail
cd "$(dirname "$0")/../.."
exe="${ACTIVEMAP:-target/release/activemap}"
episodes="${1:-10}"
steps="${2:-60}"
work="$(mktemp -d)"
trap 'kill "${daemon:-0}" 2>/dev/null || true; rm -rf "$work"' EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
control="tcp/127.0.0.1:$(free_port)"
data="tcp/127.0.0.1:$(free_port)"
flow="$work/soak.yaml"
{ printf 'machines:\n  - id: local\n    listen: [%s]\n' "$data"; cat dataflow.yaml; } > "$flow"
"$exe" up --machine local --listen "$control" --runs "$work/runs" 2> "$work/daemon.log" &
daemon=$!
sample() {
    local fds rss shm
    fds=$(ls "/proc/$daemon/fd" | wc -l)
    rss=$(awk '/VmRSS/ {print $2}' "/proc/$daemon/status")
    shm=$(ls /dev/shm | wc -l)
    echo "$fds $rss $shm"
}
printf '%-8s %-8s %-10s %-12s %-10s %s\n' episode status seconds daemon_fds rss_kb dev_shm
failed=0
first=""
last=""
for i in $(seq 1 "$episodes"); do
    start=$(date +%s.%N)
    status=ok
    for try in $(seq 1 40); do
        if "$exe" start "$flow" --connect "$control" --run-id "soak$i" --wait --max-steps "$steps" \
            --set sim.scene=house:3 --set sim.max_rooms=2 --set sim.max_area=30 \
            --set sim.width=64 --set sim.height=64 \
            --set evaluator.scene=house:3 --set evaluator.max_rooms=2 --set evaluator.max_area=30 \
            > "$work/start$i.log" 2>&1; then
            status=ok
            break
        fi
        status=failed
        # The daemon may not listen yet before the first episode.
        grep -q "no daemon" "$work/start$i.log" || break
        sleep 0.25
    done
    end=$(date +%s.%N)
    read -r fds rss shm < <(sample)
    printf '%-8s %-8s %-10.1f %-12s %-10s %s\n' "$i" "$status" "$(echo "$end - $start" | bc)" "$fds" "$rss" "$shm"
    if [ "$status" != ok ]; then
        failed=1
        sed 's/^/    /' "$work/start$i.log" | tail -20
    fi
    [ "$i" -eq 2 ] && first="$fds $shm"
    last="$fds $shm"
done
"$exe" down --connect "$control" > /dev/null 2>&1 || true
wait "$daemon" || true
if [ -n "$first" ]; then
    read -r f0 s0 <<< "$first"
    read -r f1 s1 <<< "$last"
    if [ "$f1" -gt "$f0" ] || [ "$s1" -gt "$s0" ]; then
        echo "GREW: descriptors $f0 -> $f1, /dev/shm entries $s0 -> $s1"
        failed=1
    fi
fi
exit "$failed"
