#!/usr/bin/env bash
# Must-show 3 of issue 19: two fresh venvs installed from requirements.lock by the
# Makefile's own recipe (`make install VENV=...`) give identical `pip freeze` outputs.
#   scripts/lock-reproducibility.sh            # prints both freezes' size and the diff
# Needs ~2 GB of disk (two venvs with torch) in ${TMPDIR:-/tmp}; removes them at the end.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
for v in a b; do
    t0=$(date +%s)
    make -C "$ROOT" -s install VENV="$WORK/venv-$v" >"$WORK/install-$v.log" 2>&1 \
        || { tail -20 "$WORK/install-$v.log"; exit 1; }
    "$WORK/venv-$v/bin/pip" freeze --all --exclude-editable >"$WORK/freeze-$v.txt"
    echo "venv $v: $(wc -l <"$WORK/freeze-$v.txt") packages, installed in $(( $(date +%s) - t0 )) s"
done
if diff -u "$WORK/freeze-a.txt" "$WORK/freeze-b.txt"; then
    echo "pip freeze identical ($(sha256sum <"$WORK/freeze-a.txt" | cut -c1-16))"
    # every installed package is the lock's version (pip, part of the venv itself, aside)
    python3 - "$ROOT/requirements.lock" "$WORK/freeze-a.txt" <<'PY'
import re, sys
norm = lambda n: re.sub(r"[-_.]+", "-", n).lower()
lock = dict((norm(m[1]), m[2]) for m in
            re.finditer(r"^([A-Za-z0-9_.-]+)==(\S+)", open(sys.argv[1]).read(), re.M))
got = dict((norm(a), b) for a, _, b in (l.strip().partition("==") for l in open(sys.argv[2])))
got.pop("pip", None)
assert got == lock, {k: (got.get(k), lock.get(k)) for k in set(got) | set(lock)
                     if got.get(k) != lock.get(k)}
print(f"and equal to requirements.lock ({len(lock)} packages)")
PY
else
    echo "pip freeze DIFFERS"; exit 1
fi
