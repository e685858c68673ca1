#!/usr/bin/env bash
# Run the 3-host example of deploy/multihost/ on ONE Linux machine, one network
# namespace per host, and check the recording.
#
#   sudo deploy/netns-demo.sh [OUT_DIR]
#
# Topology (all of it inside namespaces created for this run; nothing is added to
# the machine's own network namespace and nothing is routed off the machine):
#
#   ns <tag>a  eth0 10.47.0.1/24 --veth--+
#   ns <tag>b  eth0 10.47.0.2/24 --veth--+-- br0 (bridge in ns <tag>sw, no address)
#   ns <tag>c  eth0 10.47.0.3/24 --veth--+
#
# <tag> is "ftnd<PID>" so concurrent runs never share a name. Steps: start host A
# (router + fusion center + recorder), wait until its services are alive as seen from
# host B, start hosts B and C (sensors + local filters) together, wait for them to end,
# stop host A (the recorder flushes), then python -m fedtrack.deploy.verify_run checks that every
# scan was fused and that tracks.jsonl equals the offline replay of measurements.jsonl.
#
# On exit, whatever happened (trap EXIT): TERM then KILL every process started here
# and every process left in the namespaces, then delete the namespaces (which deletes
# their links and the bridge).
#
# Environment: FEDTRACK_PYTHON (interpreter with fedtrack installed; default the
# repository's .venv/bin/python, else python3), NETNS_DEMO_TIMEOUT_S (whole run, default
# 80), NETNS_DEMO_SUBNET (first three octets, default 10.47.0).
# Exit codes: 0 verified, 1 failed (reason printed), 77 cannot run here (not root, no
# `ip`, or network namespaces unavailable; reason printed).
set -euo pipefail

NAME=netns-demo
TAG="ftnd$$"
TIMEOUT_S=${NETNS_DEMO_TIMEOUT_S:-80}
SUBNET=${NETNS_DEMO_SUBNET:-10.47.0}
SUBNET_VAR=NETNS_DEMO_SUBNET
OUT=${1:-}  # none: a new folder, made after the preflight (netns_out)
# shellcheck source=deploy/netns-common.sh
source "$(dirname "${BASH_SOURCE[0]}")/netns-common.sh"

# ------------------------------------------------------------------ preflight
netns_preflight
for f in host-a.toml host-b.toml host-c.toml; do
    [[ -f $HERE/multihost/$f ]] || fail "missing $HERE/multihost/$f"
done
netns_out fedtrack-netns
log "run $TAG, output in $OUT, python $PY, timeout ${TIMEOUT_S}s"

# ------------------------------------------------------------------ network
netns_network

# ------------------------------------------------------------------ configs
# The repository's host files name host A as 10.47.0.1; rewrite to this run's subnet.
mkdir -p "$OUT/config"
for h in "${HOSTS[@]}"; do
    sed "s/10\.47\.0\.1/$(addr a)/g" "$HERE/multihost/host-$h.toml" >"$OUT/config/host-$h.toml"
done
grep -q "tcp/$(addr a):7447" "$OUT/config/host-b.toml" || fail "host-b.toml does not connect to tcp/$(addr a):7447"

# ------------------------------------------------------------------ run
launch() {  # launch HOST: fedtrack launch in namespace <tag>HOST, bounded by the remaining time
    local h=$1
    (cd "$REPO" && exec timeout --kill-after=10 "$(remaining)" ip netns exec "$TAG$h" \
        "$PY" -m fedtrack.cli launch "$OUT/config/host-$h.toml" --out "$OUT/host-$h") \
        >"$OUT/launch-$h.log" 2>&1 &
    PIDS+=($!)
}

launch a
PID_A=${PIDS[-1]}
log "host A ($(addr a)) started: router, fusion-center, recorder"
(cd "$REPO" && timeout "$(remaining)" ip netns exec "${TAG}b" "$PY" -m fedtrack.deploy.wait_ready \
    --connect "tcp/$(addr a):7447" --deployment multihost --timeout 45 fusion-center/fusion recorder/recorder) \
    2>"$OUT/wait-ready.log" || fail "host A not reachable/ready from host B: $(tail -n 3 "$OUT/wait-ready.log"); host A log: $(tail -n 5 "$OUT/launch-a.log")"
log "host A is up as seen from host B ($(addr b)); starting hosts B and C"
launch b
PID_B=${PIDS[-1]}
launch c
PID_C=${PIDS[-1]}
wait_rc "$PID_B" RC_B
wait_rc "$PID_C" RC_C
log "host B exited $RC_B, host C exited $RC_C; stopping host A"
kill -TERM "$PID_A" 2>/dev/null || true
wait_rc "$PID_A" RC_A
for h in b c; do
    rc_var=RC_${h^^}
    [[ ${!rc_var} == 0 ]] || fail "host ${h^^} exited ${!rc_var} (124 = timeout): $(tail -n 8 "$OUT/launch-$h.log")"
done
# host A never ends by itself (no sensors): 130 is its answer to our SIGTERM
[[ $RC_A == 0 || $RC_A == 130 ]] || fail "host A exited $RC_A: $(tail -n 8 "$OUT/launch-a.log")"
tail -n 1 "$OUT/launch-b.log" | sed 's/^/netns-demo: host B: /' >&2
tail -n 1 "$OUT/launch-c.log" | sed 's/^/netns-demo: host C: /' >&2

# ------------------------------------------------------------------ verify
(cd "$REPO" && "$PY" -m fedtrack.deploy.verify_run --config "$OUT/config/host-a.toml" --run "$OUT/host-a") \
    >"$OUT/verify.json" || fail "verification: $(cat "$OUT/verify.json")"
log "verified: $(cat "$OUT/verify.json")"
log "OK in $((SECONDS - START)) s"
