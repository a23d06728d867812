"""The lock files (issue 19): every install - `make install/run/test`, CI, the Docker image -
comes from requirements.lock, every package pinned with its sha256, the CPU torch wheel,
nothing from CUDA; the Ray extra's lock agrees with it.  (That two fresh venvs from the
lock freeze identically is shown by scripts/lock-reproducibility.sh, too slow for a test.)"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements.lock"
RAY_LOCK = ROOT / "requirements-ray.lock"


def _entries(path: Path) -> dict[str, tuple[str, list[str]]]:
    """name -> (pinned version, sha256 hashes) of a pip-compile --generate-hashes file."""
    out: dict[str, tuple[str, list[str]]] = {}
    text = path.read_text()
    for block in re.split(r"\n(?=[A-Za-z0-9])", text):
        m = re.match(r"([A-Za-z0-9_.-]+)==(\S+)", block)
        if not m:
            assert block.startswith("#"), f"{path.name}: not a pinned requirement: {block[:60]}"
            continue
        hashes = re.findall(r"--hash=sha256:([0-9a-f]{64})", block)
        out[canonicalize_name(m[1])] = (m[2], hashes)
    return out


def test_every_package_is_pinned_with_a_hash() -> None:
    for path in (LOCK, RAY_LOCK):
        entries = _entries(path)
        assert len(entries) > 50
        for name, (version, hashes) in entries.items():
            assert hashes, f"{path.name}: {name}=={version} has no --hash"


def test_cpu_torch_and_no_cuda() -> None:
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    torch_req = next(Requirement(r) for r in pyproject["project"]["dependencies"]
                     if r.startswith("torch"))
    for path in (LOCK, RAY_LOCK):
        entries = _entries(path)
        version = Version(entries["torch"][0])
        assert version.local == "cpu", f"{path.name}: torch {version} is not the CPU wheel"
        assert torch_req.specifier.contains(version.public), (torch_req, version)
        cuda = [n for n in entries if n.startswith(("nvidia-", "triton", "cuda"))]
        assert not cuda, f"{path.name}: CUDA packages {cuda}"


def test_the_lock_covers_pyproject() -> None:
    """Every dependency (and test extra) is in the lock at a version pyproject allows; the
    Ray lock is the same pins plus Ray's."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    lock, ray_lock = _entries(LOCK), _entries(RAY_LOCK)
    reqs = pyproject["dependencies"] + pyproject["optional-dependencies"]["test"]
    for r in map(Requirement, reqs):
        name = canonicalize_name(r.name)
        assert name in lock, f"{r} is not in requirements.lock: make lock"
        assert r.specifier.contains(Version(lock[name][0]).public, prereleases=True), (r, lock[name])
    for r in map(Requirement, pyproject["optional-dependencies"]["ray"]):
        assert r.specifier.contains(ray_lock[canonicalize_name(r.name)][0])
    assert {n: v for n, (v, _) in ray_lock.items() if n in lock} == \
        {n: v for n, (v, _) in lock.items()}


def test_installs_use_the_lock_with_hashes() -> None:
    make = (ROOT / "Makefile").read_text()
    assert "--require-hashes --no-deps -r $(LOCK)" in make
    assert "--require-hashes --no-deps -r $(RAY_LOCK)" in make
    assert "$(STAMP): pyproject.toml $(LOCK)" in make
    # the project itself: no dependency resolution, no build-isolation downloads
    assert "--no-deps --no-build-isolation -e ." in make
    docker = (ROOT / "docker" / "Dockerfile").read_text()
    assert "--require-hashes" in docker and "requirements.lock" in docker
    assert "make test-platform" in (ROOT / ".ci" / "run").read_text()
