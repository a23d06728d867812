"""`SivaClient` and `siva-client` against the real server, plus offline error handling."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]
DUFFING = Path(os.environ.get("SIVA_SHARED_DATA") or ROOT.parent / "shared" / "data") / "duffing"
sys.path.insert(0, str(ROOT))
from tests.conftest import find_shared_data  # noqa: E402

DUFFING = (find_shared_data() or ROOT.parent / "shared" / "data") / "duffing"

from clients import SivaClient, SivaClientError  # noqa: E402
from clients.cli import main as cli_main  # noqa: E402
from clients.client import folder_plan  # noqa: E402
from service.demo import ServerThread  # noqa: E402
from service.settings import Settings  # noqa: E402

SPEC = ROOT / "examples" / "models" / "duffing.toml"
TOKEN = "s3cret-token"


def small(name: str, offset: int = 0) -> bytes:
    lines = (DUFFING / name).read_text().splitlines()
    return ("\n".join([lines[0]] + lines[1 + offset::10]) + "\n").encode()


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory):
    """(base URL, data directory) of one real server for the module."""
    data = tmp_path_factory.mktemp("client-data")
    st = Settings(data_dir=data, api_token=TOKEN, snapshot_every=2)
    with ServerThread(st) as url:
        yield url, data


@pytest.fixture(scope="module")
def server(served) -> str:
    return served[0]


def test_register_upload_estimate_round_trip(server: str, tmp_path: Path) -> None:
    with SivaClient(server, token=TOKEN) as c:
        assert c.health()
        ack = c.register("rt", SPEC)
        assert ack["created"] is True and ack["free_parameters"] == ["b", "b_nl", "k", "k_nl"]
        assert c.register("rt", SPEC)["created"] is False  # same spec again: 200
        f = tmp_path / "train_v5.csv"
        f.write_bytes(small("train_v5.csv"))
        up = c.upload("rt", f, role="train")
        assert up["id"] and up["role"] == "train" and up["filename"] == "train_v5.csv"
        up2 = c.upload("rt", small("val_v3.csv"), role="val")
        assert up2["role"] == "validation"
        assert c.upload("rt", f)["duplicate"] is True
        recs = c.recordings("rt")
        assert [r["id"] for r in recs["recordings"]] == [up["id"], up2["id"]]
        deadline = time.monotonic() + 120
        while c.estimate("rt")["epoch"] < 2:
            assert time.monotonic() < deadline
            time.sleep(0.1)
        est = c.estimate("rt")
        assert set(est["parameters"]) == {"b", "b_nl", "k", "k_nl"}
        assert est["n_recordings"] == {"train": 1, "validation": 1}
        assert "history" in c.drift("rt")


def test_server_detail_becomes_the_error_message(server: str) -> None:
    with SivaClient(server, token=TOKEN) as c:
        with pytest.raises(SivaClientError) as e:
            c.estimate("nope")
        assert e.value.status == 404 and "does not exist" in str(e.value)
        c.register("errs", SPEC)
        with pytest.raises(SivaClientError) as e:
            bad = "time,acc_x\n" + "".join(f"{i / 10},{'nan' if i == 7 else 1}\n" for i in range(30))
            c.upload("errs", bad.encode(), role="train")
        assert e.value.status == 422 and "'acc_x'" in e.value.detail and "row" in e.value.detail
        with pytest.raises(SivaClientError) as e:
            c.register("errs", {**json.loads(json.dumps(_toml(SPEC))), "dofs": ["y"]})
        assert e.value.status in (409, 422)
    with SivaClient(server) as anon:  # no token: writes refused, reads fine
        with pytest.raises(SivaClientError) as e:
            anon.register("x", SPEC)
        assert e.value.status == 401 and "Bearer" in str(e.value)
        assert anon.health()


def test_wait_converged_times_out_cleanly(server: str) -> None:
    with SivaClient(server, token=TOKEN) as c:
        c.register("idle", SPEC)  # no recordings: never converges
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match="idle: not converged"):
            c.wait_converged("idle", timeout=0.6, poll=0.2)
        assert time.monotonic() - t0 < 10


def test_upload_folder_roles(tmp_path: Path) -> None:
    (tmp_path / "train").mkdir()
    (tmp_path / "val").mkdir()
    (tmp_path / "train" / "a.csv").write_text("x")
    (tmp_path / "val" / "b.csv").write_text("x")
    (tmp_path / "val_c.csv").write_text("x")
    (tmp_path / "d.json").write_text("x")
    (tmp_path / "notes.txt").write_text("x")  # not a recording suffix
    (tmp_path / ".hidden.csv").write_text("x")
    plan = [(p.relative_to(tmp_path).as_posix(), r) for p, r in folder_plan(tmp_path)]
    assert plan == [("d.json", None), ("train/a.csv", "train"), ("val/b.csv", "validation"),
                    ("val_c.csv", "validation")]
    assert {r for _, r in folder_plan(tmp_path, "train")} == {"train"}
    with pytest.raises(SivaClientError, match="not a folder"):
        folder_plan(tmp_path / "missing")


def test_offline_errors_are_clear() -> None:
    with SivaClient("http://127.0.0.1:9") as c:  # nothing listens on the discard port
        with pytest.raises(SivaClientError, match="cannot reach the siva service"):
            c.estimate("x")
        assert c.health() is False
        with pytest.raises(SivaClientError, match="unknown recording format"):
            c.upload("x", b"...", fmt="xlsx")
        with pytest.raises(SivaClientError, match="role must be"):
            c.upload("x", b"...", role="test")
        with pytest.raises(SivaClientError, match="cannot read"):
            c.upload("x", "/nonexistent/file.csv")


def test_validation_error_lists_are_flattened() -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(422, json={"detail": [{"loc": ["query", "role"], "msg": "bad"}]})

    with SivaClient("http://x", transport=httpx.MockTransport(handler)) as c:
        with pytest.raises(SivaClientError, match=r"422 query\.role: bad"):
            c.drift("s")

    def plain(request: httpx.Request) -> httpx.Response:
        return httpx.Response(502, text="Bad Gateway from proxy")

    with SivaClient("http://x", transport=httpx.MockTransport(plain)) as c:
        with pytest.raises(SivaClientError, match="502 Bad Gateway from proxy"):
            c.estimate("s")


def test_bearer_token_and_content_types_sent() -> None:
    seen: list[httpx.Request] = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        return httpx.Response(202, json={"id": "r1"})

    with SivaClient("http://x/", token="tok", transport=httpx.MockTransport(handler)) as c:
        c.upload("my sys", b"{}", fmt="json", role="train")
        c.upload("s", b"PK..", fmt="npz")
    r = seen[0]
    assert r.headers["authorization"] == "Bearer tok"
    assert r.headers["content-type"] == "application/json"
    assert r.url.path == "/v1/systems/my%20sys/recordings" or r.url.raw_path.startswith(
        b"/v1/systems/my%20sys/recordings")
    assert r.url.params["role"] == "train"
    assert seen[1].headers["content-type"] == "application/x-npz"
    assert "role" not in seen[1].url.params


def _toml(path: Path) -> dict:
    import tomllib

    return tomllib.loads(path.read_text())


def _cli(args: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    code = cli_main(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_commands(server: str, tmp_path: Path, capsys: pytest.CaptureFixture,
                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SIVA_URL", server)
    monkeypatch.setenv("SIVA_API_TOKEN", TOKEN)
    code, out, _ = _cli(["register", "cli", str(SPEC), "--json"], capsys)
    assert code == 0 and json.loads(out)["name"] == "cli"
    (tmp_path / "train").mkdir()
    (tmp_path / "val").mkdir()
    (tmp_path / "train" / "t.csv").write_bytes(small("train_v5.csv"))
    (tmp_path / "val" / "v.csv").write_bytes(small("val_v3.csv"))
    code, out, _ = _cli(["--json", "upload-folder", "cli", str(tmp_path)], capsys)
    acks = json.loads(out)
    assert code == 0 and [a["role"] for a in acks] == ["train", "validation"]
    extra = tmp_path / "t2.csv"
    extra.write_bytes(small("train_v5.csv", offset=3))
    code, out, _ = _cli(["upload", "cli", str(extra), "--role", "train", "--json"], capsys)
    assert code == 0 and json.loads(out)["role"] == "train"
    code, out, _ = _cli(["recordings", "cli", "--json"], capsys)
    assert len(json.loads(out)["recordings"]) == 3
    deadline = time.monotonic() + 120
    while True:
        code, out, _ = _cli(["estimate", "cli", "--json"], capsys)
        if json.loads(out)["epoch"] >= 4:
            break
        assert time.monotonic() < deadline
        time.sleep(0.2)
    code, out, _ = _cli(["drift", "cli", "--watch", "--json", "--interval", "0.1", "--count", "2"],
                        capsys)
    lines = [json.loads(x) for x in out.splitlines()]
    assert code == 0 and lines and all(x["event"] in ("estimate", "alarm") for x in lines)
    assert all(isinstance(v, (float, type(None))) for v in lines[0]["parameters"].values())
    # human-readable: a table with units from the element kinds, 4 significant digits
    code, out, _ = _cli(["estimate", "cli"], capsys)
    assert code == 0 and "parameter" in out and "N/m³" in out and "95 % interval" in out
    assert not out.lstrip().startswith("{")
    code, out, _ = _cli(["drift", "cli", "--watch", "--interval", "0.1", "--count", "2"], capsys)
    assert code == 0 and out.splitlines()[0].split()[:2] == ["epoch", "time"]
    assert "converged" in out.splitlines()[0]
    assert "k [N/m]" in out.splitlines()[0]
    code, out, _ = _cli(["drift", "reset", "cli", "--json"], capsys)
    assert code == 0 and json.loads(out)["alarms"] == []
    # errors: the server's detail on stderr, exit 1; a wrong token is a 401
    code, _, err = _cli(["estimate", "missing"], capsys)
    assert code == 1 and "404" in err and "does not exist" in err
    code, _, err = _cli(["--token", "wrong", "register", "z", str(SPEC)], capsys)
    assert code == 1 and "401" in err
    code, _, err = _cli(["--url", "http://127.0.0.1:9", "estimate", "cli"], capsys)
    assert code == 1 and "cannot reach" in err


def test_console_script_is_installed() -> None:
    exe = Path(sys.executable).with_name("siva-client")
    if not exe.exists():
        pytest.skip("package not installed with its console scripts")
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "SIVA_URL": "http://127.0.0.1:9"})
    assert out.returncode == 0 and "upload-folder" in out.stdout and "SIVA_API_TOKEN" in out.stdout


# ------------------------------------------------------------------ deployment (docker/)
# No docker engine runs here: check what can be checked without one.
DOCKER = ROOT / "docker"


def _dockerfile() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with line continuations joined and comments dropped."""
    text = (DOCKER / "Dockerfile").read_text().replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


def test_dockerfile_builds_what_the_repo_has() -> None:
    import shlex
    import tomllib

    steps = _dockerfile()
    assert steps[:2] == [("ARG", "BASE_IMAGE=python:3.11-slim"), ("FROM", "${BASE_IMAGE}")]
    args = dict(a.split("=", 1) for k, a in steps if k == "ARG")
    assert "SIVA_REQUIRE_TOKEN=1" in next(a for k, a in steps if k == "ENV")
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert f"torch=={args['TORCH_VERSION']}" in pyproject["project"]["dependencies"]
    runs = [a for k, a in steps if k == "RUN"]
    # torch first (its own layer), then the rest: all from requirements.lock, hash-checked
    torch_run = next(r for r in runs if "torch==" in r)
    rest = next(i for i, r in enumerate(runs) if "-r /tmp/requirements.lock" in r)
    assert runs.index(torch_run) < rest
    for r in (torch_run, runs[rest]):
        assert "--require-hashes --no-deps" in r
    assert "--no-deps --no-build-isolation ." in runs[rest]
    assert "--extra-index-url" in torch_run and "whl/cpu" in args["TORCH_INDEX_URL"]
    lock = (ROOT / "requirements.lock").read_text()
    assert f"\ntorch=={args['TORCH_VERSION']}+cpu " in lock
    for k, a in steps:
        if k == "COPY":
            *sources, _dest = shlex.split(a)
            for src in sources:
                assert (ROOT / src).exists(), f"COPY {src}: not in the repository"
    packages = pyproject["tool"]["setuptools"]["packages"]["find"]["include"]
    copied = {shlex.split(a)[0] for k, a in steps if k == "COPY"}
    assert {p.rstrip("*") for p in packages} <= copied
    cmd = json.loads(next(a for k, a in steps if k == "CMD"))
    assert cmd == ["siva", "serve", "--host", "0.0.0.0", "--data-dir", "/data"]
    assert "siva" in pyproject["project"]["scripts"]
    from siva_cli import build_parser

    ns = build_parser().parse_args(cmd[1:])
    assert (ns.command, ns.host, ns.data_dir, ns.port) == ("serve", "0.0.0.0", "/data", 8000)
    assert ("EXPOSE", "8000") in steps and ("USER", "siva") in steps
    health = next(a for k, a in steps if k == "HEALTHCHECK")
    assert "/healthz" in health and ":8000" in health
    compile(json.loads(health.split("CMD", 1)[1])[2], "<healthcheck>", "exec")


def test_compose_file() -> None:
    import yaml

    doc = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    svc = doc["services"]["siva"]
    ctx = (DOCKER / svc["build"]["context"]).resolve()
    assert ctx == ROOT and (ctx / svc["build"]["dockerfile"]).is_file()
    assert svc["ports"] == ["${SIVA_BIND:-127.0.0.1}:${SIVA_PORT:-8000}:8000"]  # localhost
    assert "SIVA_REQUIRE_TOKEN=${SIVA_REQUIRE_TOKEN:-1}" in svc["environment"]
    vol, _, target = svc["volumes"][0].split()[0].partition(":")
    assert target == "/data" and vol in doc["volumes"]  # a named volume, not a bind mount
    assert "SIVA_API_TOKEN" in svc["environment"]  # passthrough (no value: taken from host)
    hc = svc["healthcheck"]["test"]
    assert hc[0] == "CMD" and any("/healthz" in part for part in hc)
    compile(hc[-1], "<healthcheck>", "exec")


@pytest.mark.parametrize("text, mb", [("3.229MB", "3.229"), ("3.229 MB", "3.229"),
                                      ("612kB", "0.612"), ("1.2GB", "1200.000"),
                                      ("850B", "0.001"), ("25MB", "25.000")])
def test_smoke_reads_docker_context_sizes_with_or_without_a_space(text: str, mb: str) -> None:
    """docker prints "3.229MB" (issue 19: the smoke failed, it expected "3.229 MB")."""
    import subprocess

    out = subprocess.run(["bash", str(DOCKER / "smoke.sh"), "--context-mb", text],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 0 and out.stdout.strip() == mb, (out.stdout, out.stderr)
    bad = subprocess.run(["bash", str(DOCKER / "smoke.sh"), "--context-mb", "lots"],
                         capture_output=True, text=True, timeout=30)
    assert bad.returncode != 0


def test_docker_context_is_small_and_has_what_copy_needs() -> None:
    """The files .dockerignore lets into the build context: every COPY source, < 20 MB."""
    import fnmatch
    import shlex

    rules = [ln.strip() for ln in (ROOT / ".dockerignore").read_text().splitlines()
             if ln.strip() and not ln.startswith("#")]

    def included(rel: str) -> bool:
        keep = False
        for rule in rules:
            neg = rule.startswith("!")
            pat = rule.lstrip("!").rstrip("/")
            hit = (fnmatch.fnmatch(rel, pat) or rel.startswith(pat + "/")
                   or fnmatch.fnmatch(rel, pat.replace("**/", "*/")) or
                   any(fnmatch.fnmatch(part, pat.replace("**/", "")) for part in rel.split("/")
                       if pat.startswith("**/")))
            if hit:
                keep = neg
        return keep

    files = [p for p in ROOT.rglob("*") if p.is_file() and ".git" not in p.parts
             and included(p.relative_to(ROOT).as_posix())]
    size = sum(p.stat().st_size for p in files)
    assert size < 20e6, size
    assert not any(".venv" in p.parts or "__pycache__" in p.parts for p in files)
    for k, a in _dockerfile():
        if k == "COPY":
            *sources, _dest = shlex.split(a)
            for src in sources:
                assert any(p.relative_to(ROOT).as_posix().startswith(src.rstrip("/"))
                           for p in files), f"COPY {src}: excluded by .dockerignore"


def test_upload_folder_skips_what_is_not_a_recording(server: str, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SIVA_URL", server)
    monkeypatch.setenv("SIVA_API_TOKEN", TOKEN)
    assert _cli(["register", "skips", str(SPEC)], capsys)[0] == 0
    (tmp_path / "a.csv").write_bytes(small("train_v5.csv"))
    (tmp_path / "b_notes.csv").write_text("this is not a recording\n")
    (tmp_path / "photo.jpg").write_bytes(b"\xff\xd8\xff")
    (tmp_path / "val_c.csv").write_bytes(small("val_v3.csv"))
    code, out, err = _cli(["upload-folder", "skips", str(tmp_path), "--json"], capsys)
    assert code == 0, err
    assert [Path(a["path"]).name for a in json.loads(out)] == ["a.csv", "val_c.csv"]
    assert "warning: skipping" in err and "photo.jpg" in err and "b_notes.csv" in err
    # delete: asks (no tty here: refused without --yes), then deletes
    code, _, err = _cli(["delete", "skips"], capsys)
    assert code == 2 and "--yes" in err
    code, out, _ = _cli(["delete", "skips", "--yes", "--json"], capsys)
    body = json.loads(out)
    assert code == 0 and body["deleted"] == "skips" and body["logs"]["action"] == "deleted"
    code, _, err = _cli(["estimate", "skips"], capsys)
    assert code == 1 and "404" in err


def test_client_content_types_cover_the_server_formats() -> None:
    from clients.client import CONTENT_TYPES
    from siva_core import RECORDING_FORMATS as REGISTRY
    from siva_core import media_types

    served = media_types()
    for fmt in REGISTRY.values():
        for suffix in fmt.suffixes:
            media = CONTENT_TYPES[suffix.lstrip(".")]
            assert served[media] == fmt.name or (fmt.name == "csv" and media == "text/csv")


def test_render_numbers_and_units() -> None:
    from clients import render

    spec = _toml(ROOT / "examples" / "models" / "lono.toml")
    units = render.parameter_units(spec)
    assert units["k1"] == "N/m" and units["b1"] == "N·s/m" and units["beta"] == "–"
    assert [render.num(x) for x in (3e8, 0.000123456, 12.3456789, None, 0)] == \
        ["3.000e+08", "1.235e-04", "12.35", "–", "0"]
    text = render.render_estimate("lono", {
        "parameters": {"k1": {"mean": 1234.5678, "std": 1.23456, "ci95": [1232.1, 1237.0]}},
        "epoch": 7, "converged": True, "n_recordings": {"train": 2, "validation": 1},
        "modal": {"frequency_hz": [19.83], "damping_ratio": [0.0123]}}, units)
    assert "1235" in text and "[1232, 1237]" in text and "N/m" in text
    assert "19.83 Hz (ζ 1.23 %)" in text and "epoch 7" in text


# ------------------------------------------------------------------ issue 17, finding 7
UNIX_FLOAT = r"\b1[6-9]\d{8}\.\d+"       # a raw UNIX time such as 1795596608.876913
LOCAL_TIME = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d"


def test_cli_prints_tables_with_units_and_local_times(
        server: str, tmp_path: Path, capsys: pytest.CaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 17, finding 7: register, upload, recordings, wait and drift reset printed raw
    JSON (drift reset ~4,500 lines, UNIX float times).  Now: tables and short summaries."""
    import re

    monkeypatch.setenv("SIVA_URL", server)
    monkeypatch.setenv("SIVA_API_TOKEN", TOKEN)
    code, out, _ = _cli(["register", "tab", str(SPEC)], capsys)
    assert code == 0 and out.startswith("tab: registered") and "{" not in out
    assert "k [N/m]" in out and "4 free parameter(s)" in out
    code, out, _ = _cli(["register", "tab", str(SPEC)], capsys)
    assert "already registered" in out
    files = []
    for i, (src, off) in enumerate((("train_v5.csv", 0), ("val_v3.csv", 0), ("train_v5.csv", 4))):
        f = tmp_path / f"r{i}.csv"
        f.write_bytes(small(src, offset=off))
        files.append(str(f))
    code, out, _ = _cli(["upload", "tab", *files[:2]], capsys)
    lines = out.splitlines()
    assert code == 0 and "fs [Hz]" in lines[0] and "duration [s]" in lines[0]
    assert "received (" in lines[0] and len(lines) == 4, out  # header, rule, one row per file
    assert re.search(LOCAL_TIME, out) and not re.search(UNIX_FLOAT, out), out
    assert "r0.csv" in out and "1000" in out  # the file, its rate (10 kHz / 10)
    code, out, _ = _cli(["upload", "tab", files[0]], capsys)
    assert "already stored" in out  # a duplicate says so
    code, out, _ = _cli(["upload", "tab", files[2], "--role", "train"], capsys)
    code, out, _ = _cli(["recordings", "tab"], capsys)
    assert code == 0 and out.startswith("tab: 3 recording(s), 2 train + 1 validation")
    assert "in training" in out and re.search(LOCAL_TIME, out) and not re.search(UNIX_FLOAT, out)
    with SivaClient(server, token=TOKEN) as c:
        deadline = time.monotonic() + 120
        while c.estimate("tab")["epoch"] < 4 or len(c.drift("tab")["history"]) < 2:
            assert time.monotonic() < deadline
            time.sleep(0.2)
        # wait prints what estimate prints (here without waiting for the refiner's best)
        monkeypatch.setattr(SivaClient, "wait", lambda self, name, *a, **k: self.estimate(name))
    code, out, _ = _cli(["wait", "tab", "--for", "converged"], capsys)
    assert code == 0 and "parameter" in out and "k" in out and "N/m" in out
    assert not out.lstrip().startswith("{") and not re.search(UNIX_FLOAT, out)
    code, out, _ = _cli(["drift", "tab"], capsys)
    assert code == 0 and re.search(LOCAL_TIME, out) and not re.search(UNIX_FLOAT, out)
    code, out, _ = _cli(["drift", "reset", "tab"], capsys)
    assert code == 0 and len(out.splitlines()) <= 3, out
    assert "forgotten" in out and "history" in out and "{" not in out
    code, out, _ = _cli(["--json", "drift", "reset", "tab"], capsys)
    assert json.loads(out)["system"] == "tab"  # --json: the server's answer, unchanged


def test_delete_removes_or_archives_the_event_logs(
        served, tmp_path: Path, capsys: pytest.CaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 17, finding 7: `delete --yes` left the system's MCAP logs behind."""
    url, data = served
    monkeypatch.setenv("SIVA_URL", url)
    monkeypatch.setenv("SIVA_API_TOKEN", TOKEN)
    f = tmp_path / "t.csv"
    f.write_bytes(small("train_v5.csv"))
    for name in ("gone", "kept"):
        assert _cli(["register", name, str(SPEC)], capsys)[0] == 0
        assert _cli(["upload", name, str(f)], capsys)[0] == 0
        assert list((data / "logs" / name).glob("*.mcap")), "the service logs every system"
    code, out, _ = _cli(["delete", "gone", "--yes"], capsys)
    assert code == 0 and "MCAP event logs were deleted" in out and "1 recording" in out, out
    assert not (data / "logs" / "gone").exists()
    code, out, _ = _cli(["delete", "kept", "--yes", "--archive-logs"], capsys)
    assert code == 0 and "archived to archive/logs/kept-" in out, out
    assert not (data / "logs" / "kept").exists()
    archived = list((data / "archive" / "logs").glob("kept-*/*.mcap"))
    assert archived, list((data / "archive").rglob("*"))
    from service.storage.eventlog import read_events
    assert any(e.topic == "/siva/recording" for e in read_events(archived[0]))  # still readable
    # the name is free again, and its new log starts afresh
    assert _cli(["register", "gone", str(SPEC)], capsys)[0] == 0
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}) as h:
        r = h.delete("/v1/systems/gone", params={"logs": "shred"})
        assert r.status_code == 422 and "archive" in r.json()["detail"]


def test_exports_csv_over_http_and_cli(served, tmp_path: Path, capsys: pytest.CaptureFixture,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Estimates, per-record fits and the drift history as CSV with units in the header."""
    import csv
    import io

    url, _ = served
    with SivaClient(url, token=TOKEN) as c:
        c.register("exp", SPEC)
        c.upload("exp", small("train_v5.csv"), role="train")
        c.upload("exp", small("val_v3.csv"), role="validation")
        deadline = time.monotonic() + 120
        while len(c.drift("exp")["history"]) < 2 or not c.estimate("exp")["parameters"]:
            assert time.monotonic() < deadline
            time.sleep(0.2)
    with httpx.Client(base_url=url) as h:
        r = h.get("/v1/systems/exp/export/estimates.csv")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
        assert 'filename="exp-estimates.csv"' in r.headers["content-disposition"]
        rows = list(csv.DictReader(io.StringIO(r.text)))
        by = {row["quantity"]: row for row in rows}
        assert set(by) >= {"b", "b_nl", "k", "k_nl"} and by["k"]["unit"] == "N/m"
        assert by["b_nl"]["unit"].isascii() and float(by["k"]["value"]) > 0
        r = h.get("/v1/systems/exp/export/drift.csv")
        head, *body = list(csv.reader(io.StringIO(r.text)))
        assert head[:2] == ["time_utc", "epoch"] and "k [N/m]" in head and "f1 [Hz]" in head
        assert len(body) >= 2 and body[0][0][:2] == "20"  # a date, not a UNIX float
        r = h.get("/v1/systems/exp/export/records.csv")
        head = next(csv.reader(io.StringIO(r.text)))
        assert r.status_code == 200 and head[:3] == ["record_index", "record_id", "received_utc"]
        assert h.get("/v1/systems/exp/export/alarms.csv").status_code == 200
        r = h.get("/v1/systems/exp/export/nope.csv")
        assert r.status_code == 404 and "estimates.csv" in r.json()["detail"]
        assert h.get("/v1/systems/missing/export/drift.csv").status_code == 404
    monkeypatch.setenv("SIVA_URL", url)
    out_file = tmp_path / "drift.csv"
    code, _, err = _cli(["export", "exp", "--what", "drift", "--out", str(out_file)], capsys)
    assert code == 0 and "drift.csv" in err and out_file.read_text().startswith("time_utc,epoch")
    code, out, _ = _cli(["export", "exp", "--what", "estimates"], capsys)
    assert code == 0 and out.startswith("quantity,unit,value,std,ci95_low,ci95_high")


def test_estimate_summary_puts_a_rejected_model_first() -> None:
    from clients import render

    est = {"parameters": {"k": {"mean": 300.0, "std": 1.0, "ci95": [298.0, 302.0]}},
           "epoch": 9, "n_recordings": {"train": 1, "validation": 1}, "time": 1.8e9,
           "validation": {"accepted": False, "statistic": 6.8, "p_value": 1e-6}}
    lines = render.render_estimate("s", est, {"k": "N/m"}).splitlines()
    assert lines[0].startswith("MODEL REJECTED") and "T = 6.8" in lines[0]
    assert "siva diagnose" in lines[0] and "as of 20" in lines[1]
    est["validation"]["accepted"] = True
    assert render.render_estimate("s", est, {}).splitlines()[0].startswith("validation: model accepted")
    del est["validation"]
    assert render.render_estimate("s", est, {}).startswith("s: ")  # no verdict, no banner
