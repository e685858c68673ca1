# Shared by deploy/netns-demo.sh and deploy/netns-regions.sh (sourced, not run): the interpreter,
# logging, the EXIT trap that kills what the run started and deletes its namespaces, the preflight
# and the network (one namespace per host a, b, c on a bridge in namespace <tag>sw).
#
# The caller sets NAME (log prefix), TAG (namespace prefix, unique per run), TIMEOUT_S, SUBNET and
# SUBNET_VAR (the environment variable that gave SUBNET, for the error) and OUT (the folder given, may not
# exist yet, or empty), then sources this file and calls netns_preflight, netns_out and netns_network.

HERE=$(cd "$(dirname "${BASH_SOURCE[1]}")" && pwd)
REPO=$(dirname "$HERE")
if [[ -n "${FEDTRACK_PYTHON:-}" ]]; then PY=$FEDTRACK_PYTHON
elif [[ -x "$REPO/.venv/bin/python" ]]; then PY=$REPO/.venv/bin/python
else PY=python3
fi
NS_SW=${TAG}sw
HOSTS=(a b c)
START=$SECONDS
PIDS=()
CREATED_NS=()

log() { printf '%s: %s\n' "$NAME" "$*" >&2; }
skip() { log "cannot run: $*"; exit 77; }
fail() { log "FAILED: $*"; exit 1; }
remaining() { echo $(( TIMEOUT_S - (SECONDS - START) )); }
addr() { case $1 in a) echo "$SUBNET.1" ;; b) echo "$SUBNET.2" ;; c) echo "$SUBNET.3" ;; esac; }

cleanup() {
    local rc=$? pid ns
    trap - EXIT INT TERM
    for pid in "${PIDS[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
    for _ in $(seq 50); do
        local alive=0
        for pid in "${PIDS[@]}"; do kill -0 "$pid" 2>/dev/null && alive=1; done
        [[ $alive == 0 ]] && break
        sleep 0.1
    done
    for pid in "${PIDS[@]}"; do kill -KILL "$pid" 2>/dev/null || true; done
    for ns in "${CREATED_NS[@]}"; do
        for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$pid" 2>/dev/null || true; done
        ip netns del "$ns" 2>/dev/null || log "warning: could not delete namespace $ns"
    done
    [[ ${#CREATED_NS[@]} -gt 0 ]] && log "cleaned up namespaces ${CREATED_NS[*]}"
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM
trap 'log "command failed (line $LINENO): $BASH_COMMAND"' ERR

wait_rc() {  # wait_rc PID VAR: wait for PID (a child of this shell), store its exit code in VAR
    local rc=0
    wait "$1" || rc=$?
    printf -v "$2" '%s' "$rc"
}

netns_preflight() {  # root, iproute2 and a well-formed subnet, or exit 77 / 1
    [[ $(id -u) == 0 ]] || skip "needs root (network namespaces), running as uid $(id -u)"
    command -v ip >/dev/null || skip "the 'ip' command (iproute2) is not installed"
    [[ $SUBNET =~ ^[0-9]+\.[0-9]+\.[0-9]+$ ]] || fail "$SUBNET_VAR must be three octets, got '$SUBNET'"
}

netns_out() {  # netns_out PREFIX: OUT made absolute; none given: a new folder made now, after the preflight (a
    # run that cannot start left an empty /tmp/PREFIX.XXXXXX behind, tour58) and removed again if namespaces fail
    if [[ -z $OUT ]]; then
        OUT=$(mktemp -d "${TMPDIR:-/tmp}/$1.XXXXXX")
        MADE_OUT=1
    fi
    mkdir -p "$OUT"
    OUT=$(cd "$OUT" && pwd)
}

netns_network() {  # the bridge namespace and one namespace per host, eth0 at addr HOST (/24)
    local h ns err
    if ! ip netns add "$NS_SW" 2>"$OUT/netns-error.txt"; then
        err=$(tr '\n' ' ' <"$OUT/netns-error.txt")
        rm -f "$OUT/netns-error.txt"
        [[ -z ${MADE_OUT:-} ]] || rmdir "$OUT"
        skip "ip netns add failed: $err"
    fi
    CREATED_NS+=("$NS_SW")
    rm -f "$OUT/netns-error.txt"
    ip -n "$NS_SW" link set lo up
    ip -n "$NS_SW" link add br0 type bridge
    ip -n "$NS_SW" link set br0 up
    for h in "${HOSTS[@]}"; do
        ns=$TAG$h
        ip netns add "$ns"
        CREATED_NS+=("$ns")
        ip -n "$ns" link set lo up
        ip -n "$ns" link add eth0 type veth peer name "port-$h" netns "$NS_SW"
        ip -n "$NS_SW" link set "port-$h" master br0
        ip -n "$NS_SW" link set "port-$h" up
        ip -n "$ns" addr add "$(addr "$h")/24" dev eth0
        ip -n "$ns" link set eth0 up
    done
}
