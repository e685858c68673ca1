#!/usr/bin/env bash
# Run the region-sharded 3-host example of deploy/multihost-regions/ on ONE Linux machine, one
# network namespace per host, one Zenoh router per host, and check live == replay --regions.
#
#   sudo deploy/netns-regions.sh [OUT_DIR]
#
# Topology (all of it inside namespaces created for this run; nothing is added to the machine's
# own network namespace and nothing is routed off the machine):
#
#   ns <tag>a  eth0 SUBNET.1/24 --veth--+   router A, recorder, picture merger, centre of x0y0
#   ns <tag>b  eth0 SUBNET.2/24 --veth--+-- br0 (bridge in ns <tag>sw)   router B -> A, s1, s2 + trackers
#   ns <tag>c  eth0 SUBNET.3/24 --veth--+   router C -> A, centre of x1y0; s3 + tracker
#
# Routers B and C join router A (deployment.router_connect); every service is a client of its own
# host's router, so traffic between hosts goes router to router. <tag> is "ftnr<PID>".
# Steps: start host A; wait until its services are up as seen from host C; start host C's router
# and centre (host-c.toml); wait until it is up; start host B and host C's sensor
# (host-c-sensors.toml) together; wait for them to end; stop host C's centre, then host A (the
# recorder flushes); then python -m fedtrack.deploy.verify_run checks that host A's recording
# (the merged pictures) equals `fedtrack replay --algorithm mtt-federated --regions config` of
# its measurements to 1e-9.
#
# On exit, whatever happened (trap EXIT): TERM then KILL every process started here and every
# process left in the namespaces, then delete the namespaces (which deletes their links and the
# bridge).
#
# Environment: FEDTRACK_PYTHON (interpreter with fedtrack installed; default the repository's
# .venv/bin/python, else python3), NETNS_REGIONS_TIMEOUT_S (whole run, default 80),
# NETNS_REGIONS_SUBNET (first three octets, default 10.47.1), NETNS_REGIONS_CONFIGS (the host
# files' folder, default deploy/multihost-regions), NETNS_REGIONS_READY_A / _C (the services to
# wait for on hosts A and C, ROLE/ID separated by spaces; defaults match the repository's files).
# Exit codes: 0 verified, 1 failed (reason printed), 77 cannot run here (not root, no `ip`, or
# network namespaces unavailable; reason printed).
set -euo pipefail

NAME=netns-regions
TAG="ftnr$$"
TIMEOUT_S=${NETNS_REGIONS_TIMEOUT_S:-80}
SUBNET=${NETNS_REGIONS_SUBNET:-10.47.1}
SUBNET_VAR=NETNS_REGIONS_SUBNET
OUT=${1:-}  # none: a new folder, made after the preflight (netns_out)
# shellcheck source=deploy/netns-common.sh
source "$(dirname "${BASH_SOURCE[0]}")/netns-common.sh"

# ------------------------------------------------------------------ preflight
netns_preflight
CONFIGS=${NETNS_REGIONS_CONFIGS:-$HERE/multihost-regions}
READY_A=${NETNS_REGIONS_READY_A:-recorder/recorder picture/picture mtt-centre/x0y0}
READY_C=${NETNS_REGIONS_READY_C:-mtt-centre/x1y0}
DEPLOYMENT=regions3
FILES=(host-a host-b host-c host-c-sensors)
for f in "${FILES[@]}"; do
    [[ -f $CONFIGS/$f.toml ]] || fail "missing $CONFIGS/$f.toml"
done
netns_out fedtrack-netns-regions
log "run $TAG, output in $OUT, python $PY, timeout ${TIMEOUT_S}s"

# ------------------------------------------------------------------ network
netns_network

# ------------------------------------------------------------------ configs
# The repository's host files name the hosts 10.47.1.1-3; rewrite them to this run's subnet.
mkdir -p "$OUT/config"
for f in "${FILES[@]}"; do
    sed "s/10\.47\.1\.\([123]\)/$SUBNET.\1/g" "$CONFIGS/$f.toml" >"$OUT/config/$f.toml"
done
grep -q "tcp/$(addr a):7447" "$OUT/config/host-b.toml" || fail "host-b.toml does not join tcp/$(addr a):7447"

# ------------------------------------------------------------------ run
launch() {  # launch HOST FILE: fedtrack launch FILE in namespace <tag>HOST, bounded by the remaining time
    local h=$1 f=$2
    # --foreground: our SIGTERM goes to the launcher alone, which stops its services in stages (centres, then
    # the merger, the recorder, the routers); without it timeout signals the whole group at once and a
    # centre's last pictures can miss the merger or a router (measured). Left-overs: the EXIT trap.
    (cd "$REPO" && exec timeout --foreground --kill-after=10 "$(remaining)" ip netns exec "$TAG$h" \
        "$PY" -m fedtrack.cli launch "$OUT/config/$f.toml" --out "$OUT/$f") >"$OUT/launch-$f.log" 2>&1 &
    PIDS+=($!)
}
ready() {  # ready FROM_HOST ROUTER_HOST SERVICES...: wait until they are up, seen through ROUTER_HOST's router
    local from=$1 router=$2
    shift 2
    (cd "$REPO" && timeout "$(remaining)" ip netns exec "$TAG$from" "$PY" -m fedtrack.deploy.wait_ready \
        --connect "tcp/$(addr "$router"):7447" --deployment "$DEPLOYMENT" --timeout 45 "$@") 2>>"$OUT/wait-ready.log"
}

launch a host-a
PID_A=${PIDS[-1]}
# shellcheck disable=SC2086  # READY_A is a list of ROLE/ID words
ready c a $READY_A || fail "host A not up as seen from host C: $(tail -n 3 "$OUT/wait-ready.log"); host A: $(tail -n 5 "$OUT/launch-host-a.log")"
log "host A ($(addr a)) is up: router, recorder, picture merger, centre of x0y0"
launch c host-c
PID_C=${PIDS[-1]}
# shellcheck disable=SC2086
ready b a $READY_C || fail "host C not up as seen from host B through host A: $(tail -n 3 "$OUT/wait-ready.log"); host C: $(tail -n 5 "$OUT/launch-host-c.log")"
log "host C ($(addr c)) is up: router joined to A's, centre of x1y0; starting the sensors of hosts B and C"
launch b host-b
PID_B=${PIDS[-1]}
launch c host-c-sensors
PID_CS=${PIDS[-1]}
wait_rc "$PID_B" RC_B
wait_rc "$PID_CS" RC_CS
log "host B exited $RC_B, host C's sensor launch exited $RC_CS; stopping host C's centre, then host A"
kill -TERM "$PID_C" 2>/dev/null || true
wait_rc "$PID_C" RC_C
kill -TERM "$PID_A" 2>/dev/null || true
wait_rc "$PID_A" RC_A
[[ $RC_B == 0 ]] || fail "host B exited $RC_B (124 = timeout): $(tail -n 8 "$OUT/launch-host-b.log")"
[[ $RC_CS == 0 ]] || fail "host C's sensors exited $RC_CS (124 = timeout): $(tail -n 8 "$OUT/launch-host-c-sensors.log")"
# hosts A and C never end by themselves (no sensors): 130 is their answer to our SIGTERM
[[ $RC_C == 0 || $RC_C == 130 ]] || fail "host C exited $RC_C: $(tail -n 8 "$OUT/launch-host-c.log")"
[[ $RC_A == 0 || $RC_A == 130 ]] || fail "host A exited $RC_A: $(tail -n 8 "$OUT/launch-host-a.log")"

# ------------------------------------------------------------------ verify
(cd "$REPO" && "$PY" -m fedtrack.deploy.verify_run --config "$OUT/config/host-a.toml" --run "$OUT/host-a") \
    >"$OUT/verify.json" 2>"$OUT/verify.log" || fail "verification: $(cat "$OUT/verify.json") $(tail -n 3 "$OUT/verify.log")"
log "verified: $(cat "$OUT/verify.json")"
log "OK in $((SECONDS - START)) s"
