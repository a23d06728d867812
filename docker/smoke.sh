#!/usr/bin/env bash
# Build the siva image on a base image and smoke-test the container:
#   context < 20 MB; no token -> refuses to start; starts with a token; /healthz 200;
#   a write without the token 401; uploads 202; the estimate converges; after a container
#   restart the recordings and the estimate are still there (named volume).
#
#   docker/smoke.sh          # finds by itself what this machine can reach (below)
#   BASE_IMAGE=python:3.11-slim TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu docker/smoke.sh
#
# What it uses when not told (each choice is printed):
#   base image   python:3.11-slim when present or pullable; else siva-base:bookworm, made
#                with `debootstrap --variant=minbase bookworm` (root; debootstrap is
#                apt-installed if missing) from the mirror of this machine's apt sources
#   torch        the CPU wheel of requirements.lock from PyTorch's CPU index when it
#                answers; else from a local folder holding torch-<version>+cpu-cp311-*.whl
#                (WHEELHOUSE, else pip's find-links, e.g. /opt/wheels), served on 127.0.0.1
#                to the build (which then uses the host network)
#   other wheels pip's default index (PyPI), hashes checked against requirements.lock
# Environment (all optional):
#   BASE_IMAGE       base image (CPython 3.11: the lock's wheels are cp311)
#   MAKE_BASE=1      create BASE_IMAGE with debootstrap even when not needed to
#   DEBIAN_MIRROR    mirror for debootstrap (default: from /etc/apt, else deb.debian.org)
#   TORCH_INDEX_URL  where torch comes from; empty: only from WHEELHOUSE
#   WHEELHOUSE       a local folder of wheels (e.g. the torch CPU wheel)
#   EXTRA_CA_CERTS   PEM files trusted during the build (a TLS-intercepting proxy)
#   PORT             host port (default 18080), bound to 127.0.0.1
#   CONVERGE_TIMEOUT seconds to wait for convergence (default 900); KEEP=1 keeps the volume
#   docker/smoke.sh --context-mb SIZE   only converts docker's size text ("3.229MB",
#                                       "3.229 MB", "612kB", "1.2GB") to MB (tested)
set -euo pipefail

# docker's human sizes (go-units: decimal kB/MB/GB, with or without a space) in MB
context_mb() {
    awk -v s="$1" 'BEGIN {
        if (!match(s, /^[0-9]+(\.[0-9]+)?/)) exit 1
        n = substr(s, 1, RLENGTH); u = substr(s, RLENGTH + 1); gsub(/[ \t]/, "", u)
        if (u == "B") f = 1e-6; else if (u == "kB" || u == "KB") f = 1e-3
        else if (u == "MB") f = 1; else if (u == "GB") f = 1e3; else exit 1
        printf "%.3f\n", n * f }'
}
if [ "${1:-}" = "--context-mb" ]; then context_mb "$2"; exit; fi

ROOT=$(cd "$(dirname "$0")/.." && pwd)
IMAGE=${IMAGE:-siva:smoke}
PORT=${PORT:-18080}
TOKEN=${TOKEN:-smoke-$RANDOM$RANDOM}
NAME=siva-smoke-$$
VOLUME=siva-smoke-data-$$
WORK=$(mktemp -d)
CONVERGE_TIMEOUT=${CONVERGE_TIMEOUT:-900}
URL=http://127.0.0.1:$PORT
SERVER_PID=""

say() { printf '[smoke %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }
fail() { say "FAIL: $*"; docker logs --tail 40 "$NAME" 2>&1 | sed 's/^/  | /' >&2 || true; exit 1; }
cleanup() {
    docker rm -f "$NAME" >/dev/null 2>&1 || true
    [ "${KEEP:-0}" = 1 ] || docker volume rm "$VOLUME" >/dev/null 2>&1 || true
    [ -z "$SERVER_PID" ] || kill "$SERVER_PID" 2>/dev/null || true
    rm -f "$ROOT"/docker/build-ca/*.crt
    rm -rf "$WORK"
}
trap cleanup EXIT

# ---------------------------------------------------------------- what this machine reaches
apt_mirror() {  # the first Debian mirror of this machine's apt sources
    { grep -hs '^URIs:' /etc/apt/sources.list.d/*.sources | awk '{print $2}'
      grep -hs '^deb ' /etc/apt/sources.list /etc/apt/sources.list.d/*.list \
          | sed 's/\[[^]]*\]//' | awk '{print $2}'; } | grep -m1 -E '^https?://' || true
}
if [ -z "${BASE_IMAGE:-}" ]; then
    if docker image inspect python:3.11-slim >/dev/null 2>&1 \
       || timeout 120 docker pull -q python:3.11-slim >/dev/null 2>&1; then
        BASE_IMAGE=python:3.11-slim
    else
        BASE_IMAGE=siva-base:bookworm
        MAKE_BASE=1
    fi
fi
say "base image: $BASE_IMAGE"
TORCH_VERSION=$(sed -n 's/^torch==\([0-9.]*\)+cpu.*/\1/p' "$ROOT/requirements.lock")
if [ -z "${TORCH_INDEX_URL+set}" ]; then
    if curl -sfL --max-time 20 -o /dev/null https://download.pytorch.org/whl/cpu/torch/; then
        TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu
    else
        TORCH_INDEX_URL=""
    fi
fi
if [ -z "$TORCH_INDEX_URL" ] && [ -z "${WHEELHOUSE:-}" ]; then
    for dir in ${PIP_FIND_LINKS:-} $(python3 -m pip config get global.find-links 2>/dev/null) \
               /opt/wheels; do
        dir=${dir#file://}
        if ls "$dir"/torch-"$TORCH_VERSION"+cpu-cp311-*.whl >/dev/null 2>&1; then
            WHEELHOUSE=$dir; break
        fi
    done
    [ -n "${WHEELHOUSE:-}" ] || fail "torch $TORCH_VERSION+cpu: PyPI has no CPU wheel, PyTorch's \
index does not answer and no local torch-$TORCH_VERSION+cpu-cp311-*.whl was found: set \
TORCH_INDEX_URL or WHEELHOUSE"
fi
say "torch $TORCH_VERSION+cpu from: ${TORCH_INDEX_URL:-no index}${WHEELHOUSE:+ + wheelhouse $WHEELHOUSE}"

# ---------------------------------------------------------------- base image (optional)
if [ "${MAKE_BASE:-0}" = 1 ] && ! docker image inspect "$BASE_IMAGE" >/dev/null 2>&1; then
    MIRROR=${DEBIAN_MIRROR:-$(apt_mirror)}
    MIRROR=${MIRROR:-http://deb.debian.org/debian}
    command -v debootstrap >/dev/null || { apt-get update -qq && apt-get install -y -qq debootstrap; }
    say "debootstrap bookworm from $MIRROR -> $BASE_IMAGE"
    debootstrap --variant=minbase bookworm "$WORK/rootfs" "$MIRROR" >"$WORK/debootstrap.log"
    tar -C "$WORK/rootfs" -c . | docker import - "$BASE_IMAGE" >/dev/null
    rm -rf "$WORK/rootfs"
fi

# ---------------------------------------------------------------- build
build_args=(--build-arg "BASE_IMAGE=$BASE_IMAGE" --build-arg "TORCH_INDEX_URL=$TORCH_INDEX_URL")
for ca in ${EXTRA_CA_CERTS:-}; do cp "$ca" "$ROOT/docker/build-ca/$(basename "${ca%.*}").crt"; done
if [ -n "${WHEELHOUSE:-}" ]; then
    WPORT=$((PORT + 1))
    python3 -m http.server "$WPORT" --bind 127.0.0.1 --directory "$WHEELHOUSE" \
        >"$WORK/wheelhouse.log" 2>&1 &
    SERVER_PID=$!
    build_args+=(--network host --build-arg "EXTRA_FIND_LINKS=http://127.0.0.1:$WPORT/")
fi
say "building $IMAGE on $BASE_IMAGE"
t0=$(date +%s)
DOCKER_BUILDKIT=0 docker build -f "$ROOT/docker/Dockerfile" -t "$IMAGE" "${build_args[@]}" "$ROOT" \
    >"$WORK/build.log" 2>&1 || { tail -30 "$WORK/build.log" >&2; fail "docker build"; }
# the legacy builder says "Sending build context to Docker daemon  3.229MB" (older versions
# "3.229 MB"), BuildKit "transferring context: 3.23MB"
context=$(grep -oE '(Sending build context to Docker daemon|transferring context:) *[0-9.]+ *[kKMG]?B' \
          "$WORK/build.log" | tail -1 | sed -E 's/.*(daemon|context:) *//')
say "built in $(( $(date +%s) - t0 )) s; build context ${context:-not reported}; image \
$(docker image inspect -f '{{.Size}}' "$IMAGE" | awk '{printf "%.0f MB", $1/1e6}')"
if [ -n "$context" ]; then
    mb=$(context_mb "$context") || fail "cannot read the build context size '$context'"
    awk -v c="$mb" 'BEGIN{exit !(c < 20)}' || fail "build context $context (>= 20 MB)"
fi

# ---------------------------------------------------------------- token required
if timeout 120 docker run --rm "$IMAGE" >"$WORK/notoken.log" 2>&1; then
    fail "the container started without SIVA_API_TOKEN"
fi
grep -q "SIVA_REQUIRE_TOKEN" "$WORK/notoken.log" || fail "no clear message without a token"
say "without a token: refused to start (as it should)"

# ---------------------------------------------------------------- start
docker volume create "$VOLUME" >/dev/null
start() {
    docker run -d --name "$NAME" -p "127.0.0.1:$PORT:8000" -e "SIVA_API_TOKEN=$TOKEN" \
        -v "$VOLUME:/data" "$IMAGE" >/dev/null
}
wait_healthy() {
    for _ in $(seq 1 120); do
        code=$(curl -s -o /dev/null -w '%{http_code}' "$URL/healthz" || true)
        [ "$code" = 200 ] && return 0
        sleep 1
    done
    fail "/healthz did not answer 200 (last: $code)"
}
start
wait_healthy
say "/healthz 200"

# ---------------------------------------------------------------- data: made by the image
chmod 777 "$WORK"
docker run --rm -i -v "$ROOT/examples/models:/models:ro" -v "$WORK:/work" "$IMAGE" python - <<'PY' || fail "making the test data in the image"
import json, tomllib
import numpy as np
from scipy.integrate import solve_ivp
spec = tomllib.load(open("/models/duffing.toml", "rb"))
json.dump(spec, open("/work/spec.json", "w"))
m, b, bnl, k, knl = 0.05, 0.5, 4000.0, 300.0, 3e8
acc = lambda x, v: -(b * v + bnl * x * x * v + k * x + knl * x ** 3) / m
for name, v0 in (("train", 5.0), ("val", 3.0)):
    t = np.arange(10001) / 10000.0
    s = solve_ivp(lambda _t, y: [y[1], acc(*y)], (0, 1), [0, v0], t_eval=t, method="DOP853",
                  rtol=1e-9, atol=1e-12)
    x, v = s.y
    np.savetxt(f"/work/{name}.csv", np.column_stack([t, x, v, acc(x, v)]), delimiter=",",
               header="time,disp_x,vel_x,acc_x", comments="", fmt="%.10e")
PY

auth=(-H "Authorization: Bearer $TOKEN")
code=$(curl -s -o /dev/null -w '%{http_code}' -X PUT -H 'Content-Type: application/json' \
       --data-binary @"$WORK/spec.json" "$URL/v1/systems/duffing")
[ "$code" = 401 ] || fail "PUT without the token gave $code, expected 401"
code=$(curl -s -o "$WORK/put.json" -w '%{http_code}' -X PUT "${auth[@]}" \
       -H 'Content-Type: application/json' --data-binary @"$WORK/spec.json" "$URL/v1/systems/duffing")
[ "$code" = 201 ] || fail "PUT spec gave $code: $(cat "$WORK/put.json")"
for role in train validation; do
    f=$WORK/$([ $role = train ] && echo train || echo val).csv
    code=$(curl -s -o "$WORK/up.json" -w '%{http_code}' -X POST "${auth[@]}" \
           -H 'Content-Type: text/csv' --data-binary @"$f" \
           "$URL/v1/systems/duffing/recordings?role=$role")
    [ "$code" = 202 ] || fail "upload ($role) gave $code: $(cat "$WORK/up.json")"
done
say "PUT spec 201, uploads 202 (401 without the token)"

# ---------------------------------------------------------------- convergence
t0=$(date +%s)
while :; do
    curl -s "$URL/v1/systems/duffing/estimate" >"$WORK/est.json" || true
    if python3 -c 'import json,sys; e=json.load(open(sys.argv[1])); sys.exit(0 if e.get("converged") else 1)' \
        "$WORK/est.json" 2>/dev/null; then break; fi
    [ $(( $(date +%s) - t0 )) -lt "$CONVERGE_TIMEOUT" ] || fail "not converged after $CONVERGE_TIMEOUT s"
    sleep 5
done
summary() { python3 - "$1" <<'PY'
import json, sys
e = json.load(open(sys.argv[1]))
print(f"epoch {e['epoch']}, " + ", ".join(f"{p}={v['mean']:.4g}" for p, v in e["parameters"].items()))
PY
}
say "converged in $(( $(date +%s) - t0 )) s: $(summary "$WORK/est.json")"

# ---------------------------------------------------------------- restart: data survive
docker restart -t 90 "$NAME" >/dev/null
wait_healthy
curl -s "$URL/v1/systems/duffing/recordings" >"$WORK/recs.json"
python3 - "$WORK/recs.json" <<'PY' || fail "recordings lost across the restart: $(cat "$WORK/recs.json")"
import json, sys
r = json.load(open(sys.argv[1]))
n = r["n_recordings"]
assert n.get("train") == 1 and n.get("validation") == 1, n
PY
curl -s "$URL/v1/systems/duffing/estimate" >"$WORK/est2.json"
say "after a restart: healthy, 1 train + 1 validation recording, estimate $(summary "$WORK/est2.json")"
say "PASS"
