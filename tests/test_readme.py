"""The first hour: the README's Python quickstart runs as written, and `ip.view` in a script neither
blocks nor leaves a server behind, and says how to keep the page.

Each script runs in a fresh interpreter in a temporary working directory (so ``runs/`` lands
there), with a token in its environment: the meshcat server it starts inherits the token, which
finds that server among the processes of everyone else on the machine.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from idapbc_pin.recovery.trigger import SMOKE_EPOCHS
from idapbc_pin.viewer import SERVER_MARKER

from .conftest import SHORT_GATE_HORIZON, SHORT_GATE_STATES

ROOT = Path(__file__).resolve().parents[1]


def quickstart() -> str:
    """The ```python block of the README's "Quickstart (Python)" section."""
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Quickstart (Python)", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the quickstart section should hold exactly one ```python block"
    return blocks[0]


#: Run before the quickstart, in the script's fresh Python: the suite's short fallback gate
#: (`conftest._short_fallback_gate`), the fast preset cut to `SMOKE_EPOCHS` epochs (the fewest that
#: `train` does not treat as a smoke run) and the ROA cut to 20 states. The quickstart itself runs as
#: written, line for line; tests/test_fallback.py holds the gate's decisions at their real values,
#: and what the whole preset reaches is the benchmarks' figure, not this test's.
PRELUDE = (f"from idapbc_pin.recovery import box_gate\n"
              f"box_gate.GATE_STATES, box_gate.GATE_HORIZON = {SHORT_GATE_STATES}, {SHORT_GATE_HORIZON}\n"
              f"from idapbc_pin.config import TrainConfig\n"
              f"_fast = TrainConfig.fast.__func__\n"
              f"TrainConfig.fast = classmethod(lambda cls, **kw: _fast(cls, **{{'epochs': {SMOKE_EPOCHS}, **kw}}))\n"
              f"import functools, idapbc_pin\n"
              f"idapbc_pin.certify = functools.partial(idapbc_pin.certify, n=4000, invariant=50)\n"
              f"_roa = idapbc_pin.roa\n"
              f"idapbc_pin.roa = lambda *a, **k: _roa(*a, **{{**k, 'n': min(k.get('n', 200), 20)}})\n")


def _servers_with(token: str) -> list[int]:
    """Running meshcat servers (see `SERVER_MARKER`) whose environment holds `token`."""
    out = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if SERVER_MARKER not in (proc / "cmdline").read_bytes().decode("utf-8", "replace"):
                continue
            if token.encode() not in (proc / "environ").read_bytes():
                continue
            state = (proc / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            out.append(int(proc.name))
    return out


def _no_server_left(token: str, grace: float = 10.0) -> bool:
    deadline = time.monotonic() + grace
    while _servers_with(token) and time.monotonic() < deadline:
        time.sleep(0.2)
    return not _servers_with(token)


def _script(code: str, cwd: Path, token: str, **kwargs) -> subprocess.Popen:
    env = {**os.environ, "IDAPBC_TEST_TOKEN": token, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-c", code], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


@pytest.mark.slow
def test_the_readme_quickstart_runs_as_written(tmp_path):
    """It trains the fast preset (cut to `SMOKE_EPOCHS` epochs), then an ROA (cut to 20 states), a
    certificate and a replay."""
    token = uuid.uuid4().hex
    proc = _script(PRELUDE + quickstart(), tmp_path, token)
    try:
        out, err = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err[-3000:]
    assert "meshcat viewer: http://127.0.0.1:" in out and ".wait()" in out
    assert "verdict:" in out  # the certificate's table
    (run_dir,) = (tmp_path / "runs" / "cartpole").iterdir()
    assert (run_dir / "certificate.json").is_file() and (tmp_path / "replay.html").stat().st_size > 100_000
    assert _no_server_left(token), "the quickstart's meshcat server outlived the script"


VIEW_SCRIPT = (
    "import idapbc_pin as ip\n"
    "viewer = ip.view('cartpole', n=1, T=0.5)\n"
    "print('url', viewer.url, flush=True)\n"
)


def test_view_in_a_script_returns_says_how_to_keep_the_page_and_leaves_no_server(tmp_path):
    token = uuid.uuid4().hex
    proc = _script(VIEW_SCRIPT, tmp_path, token)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("meshcat viewer: http://127.0.0.1:")
    assert lines[1].startswith("note: ") and ".wait()" in lines[1] and ".write_html(" in lines[1]
    assert lines[2].startswith("url http://127.0.0.1:")
    assert _no_server_left(token)


def test_viewer_wait_serves_until_ctrl_c_then_the_script_ends_with_its_server(tmp_path):
    token = uuid.uuid4().hex
    code = VIEW_SCRIPT + "viewer.wait()\nprint('after wait', viewer.url is not None, flush=True)\n"
    proc = _script(code, tmp_path, token)
    try:
        deadline = time.monotonic() + 120
        line = ""
        while not line.startswith("url "):
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            line = proc.stdout.readline()
        time.sleep(1.0)
        assert proc.poll() is None, "viewer.wait() returned while the server runs"
        assert len(_servers_with(token)) == 1
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "after wait True" in out
    assert _no_server_left(token)


def test_view_in_an_interactive_session_prints_no_script_note(tmp_path):
    token = uuid.uuid4().hex
    code = "import sys; sys.ps1 = '>>> '\n" + VIEW_SCRIPT
    proc = _script(code, tmp_path, token)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "meshcat viewer: http://127.0.0.1:" in out and "note:" not in out
    assert _no_server_left(token)
