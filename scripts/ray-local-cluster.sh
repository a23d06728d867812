#!/usr/bin/env bash
# A local two-node Ray cluster on loopback, for `make test-ray` and the fleet benchmark.
#
#   scripts/ray-local-cluster.sh start   # head + a second node; prints the address
#   scripts/ray-local-cluster.sh stop
#
# Both nodes run on this machine (two raylets, each with its own worker processes, object
# store and logical CPUs), which is what a second machine looks like to Ray's scheduler.
# Settings (environment): RAY_BIN (default: the project's .venv/bin/ray, else `ray` on PATH),
# SIVA_RAY_PORT (6390), SIVA_RAY_NODE_CPUS (logical CPUs per node, 4: more than the cores,
# so that many systems' actors can be placed; the OS shares the real cores between them),
# SIVA_RAY_OBJECT_STORE_BYTES (per node, 200 MB), SIVA_RAY_TEMP_DIR (/tmp/ray-siva-PORT).
set -euo pipefail
HERE=$(cd "$(dirname "$0")/.." && pwd)
RAY=${RAY_BIN:-}
[ -z "$RAY" ] && [ -x "$HERE/.venv/bin/ray" ] && RAY="$HERE/.venv/bin/ray"
[ -z "$RAY" ] && RAY=$(command -v ray || true)
if [ -z "$RAY" ]; then
  echo "ray is not installed: pip install '.[ray]'" >&2
  exit 2
fi
PORT=${SIVA_RAY_PORT:-6390}
CPUS=${SIVA_RAY_NODE_CPUS:-4}
STORE=${SIVA_RAY_OBJECT_STORE_BYTES:-200000000}
# one temp dir per port: `stop` ends this cluster only, not other Ray clusters on the machine
TMP=${SIVA_RAY_TEMP_DIR:-/tmp/ray-siva-$PORT}
export RAY_USAGE_STATS_ENABLED=0
case "${1:-}" in
  start)
    "$RAY" start --head --node-ip-address=127.0.0.1 --port="$PORT" --num-cpus="$CPUS" \
      --object-store-memory="$STORE" --include-dashboard=false --disable-usage-stats \
      --temp-dir="$TMP" >/dev/null
    "$RAY" start --address="127.0.0.1:$PORT" --node-ip-address=127.0.0.1 --num-cpus="$CPUS" \
      --object-store-memory="$STORE" >/dev/null
    for _ in $(seq 1 60); do  # wait until both nodes are registered
      n=$("$RAY" status --address="127.0.0.1:$PORT" 2>/dev/null | grep -c '^ 1 node_' || true)
      [ "$n" -ge 2 ] && { echo "127.0.0.1:$PORT"; exit 0; }
      sleep 1
    done
    echo "the second Ray node did not join in 60 s" >&2
    exit 1 ;;
  stop)
    # every daemon of this cluster names its session dir under $TMP; its agents and
    # workers are their descendants: collect the whole tree, then kill it
    pids=$(pgrep -f -- "$TMP/" || true)
    all=""
    while [ -n "$pids" ]; do
      all="$all $pids"
      pids=$(for p in $pids; do pgrep -P "$p" || true; done)
    done
    [ -n "$all" ] && kill -9 $all >/dev/null 2>&1 || true
    for _ in $(seq 1 20); do
      pgrep -f -- "$TMP/" >/dev/null || exit 0
      sleep 0.5
    done
    echo "some processes of the cluster under $TMP did not exit" >&2
    exit 1 ;;
  *)
    echo "usage: $0 start|stop" >&2
    exit 2 ;;
esac
