#!/usr/bin/env bash
# A local two-node Ray cluster on loopback, for `make test-ray` and the fleet benchmark.
#
#   scripts/ray-local-cluster.sh start   # head + a second node; prints the address
#   scripts/ray-local-cluster.sh stop
#
# Both nodes run on this machine (two raylets, each with its own worker processes, object
# store and logical CPUs), which is what a second machine looks like to Ray's scheduler.
# Settings (environment): RAY_BIN (default: the `ray` next to the python in use / on PATH),
# SIVA_RAY_PORT (6390), SIVA_RAY_NODE_CPUS (logical CPUs per node, 4: more than the cores,
# so that many systems' actors can be placed; the OS shares the real cores between them),
# SIVA_RAY_OBJECT_STORE_BYTES (per node, 200 MB).
set -euo pipefail
RAY=${RAY_BIN:-$(command -v ray || true)}
if [ -z "$RAY" ]; then
  echo "ray is not installed: pip install '.[ray]'" >&2
  exit 2
fi
PORT=${SIVA_RAY_PORT:-6390}
CPUS=${SIVA_RAY_NODE_CPUS:-4}
STORE=${SIVA_RAY_OBJECT_STORE_BYTES:-200000000}
export RAY_USAGE_STATS_ENABLED=0
case "${1:-}" in
  start)
    "$RAY" start --head --node-ip-address=127.0.0.1 --port="$PORT" --num-cpus="$CPUS" \
      --object-store-memory="$STORE" --include-dashboard=false --disable-usage-stats \
      >/dev/null
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
    "$RAY" stop --force >/dev/null 2>&1 || true ;;
  *)
    echo "usage: $0 start|stop" >&2
    exit 2 ;;
esac
